"""Archive reprocessing (docs/reprocess.md): the plan of chunks, the tasks run on Dask workers,
the cluster and its single writer, and a campaign's camera registration rebuilt from its record.

May import :mod:`~controller.calibration.cycle` (the beam chain),
:mod:`~controller.calibration.model` and :mod:`~controller.calibration.records`.
"""
