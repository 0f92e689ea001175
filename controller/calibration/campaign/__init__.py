"""A campaign: a queue of heliostats run through the cycle on one field, the field itself (its
devices, records and time), several targets in parallel, the order of the queue, how a session
ended and the lights out at every end.

May import :mod:`~controller.calibration.cycle`, :mod:`~controller.calibration.beams`,
:mod:`~controller.calibration.model` and :mod:`~controller.calibration.records`; never the
night (which runs campaigns) or reprocessing.
"""
