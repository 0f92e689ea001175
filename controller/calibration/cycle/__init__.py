"""One heliostat's measurement cycle: the state machine and what it talks to — pointing and
beam-safe moves (approach, park), the target gate, exposure, the beam chain of a capture, the
correction step, camera registration, commissioning, the model update after a run, and the
state-machine diagram.

May import :mod:`controller.calibration.records`, the drivers, the pure domain and
``controller.io``; no other calibration sub-package (they are all built on the cycle).
"""
