"""Several beams on one target (``calibration.beams_per_target`` K > 1, lamps at night): when
they may share it, the slots they aim at, the shared capture and the known step that tells
whose spot is whose (the target gate handing out slots is the cycle's,
:mod:`controller.calibration.cycle.gate`).

May import :mod:`~controller.calibration.records` and :mod:`~controller.calibration.cycle`;
never the campaign, the night or reprocessing.
"""
