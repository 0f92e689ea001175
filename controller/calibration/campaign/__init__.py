"""A campaign: the field it runs on (its devices, records and time), a queue of heliostats run
through the cycle, several targets in parallel, the order of the queue, recovery when no beam is
seen, clearing the targets and changing the lamp without a stray beam, how a session ended, the
lights out at every end, and the observers a campaign reports to.

May import :mod:`~controller.calibration.records`, :mod:`~controller.calibration.cycle` and
:mod:`~controller.calibration.beams`; never the night (which runs campaigns) or reprocessing.
"""
