"""Several beams on one target (``calibration.beams_per_target`` K > 1, lamps at night): when
they may share it, the target gate handing out beams and slots, the shared capture and the known
step that tells whose spot is whose.

May import :mod:`~controller.calibration.records`, the drivers and the pure domain; never the
cycle, the campaign or the night.
"""
