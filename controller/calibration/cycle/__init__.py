"""One heliostat's measurement cycle: the state machine and what it talks to — pointing and
beam-safe moves (approach, park), exposure, the beam chain of a capture, the correction step,
camera registration, no-beam recovery, commissioning, and the state-machine diagram.

May import :mod:`controller.calibration.records` and :mod:`controller.calibration.beams`
(the target gate), the drivers, the pure domain and ``controller.io``; never the campaign,
the night, the model update or reprocessing (they are built on the cycle).
"""
