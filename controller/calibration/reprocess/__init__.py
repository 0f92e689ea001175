"""Archive reprocessing (docs/reprocess.md): the plan of chunks, the tasks run on Dask workers,
the cluster and its single writer, and a campaign's camera registration rebuilt from its record.

The top of the calibration package: may import every other calibration sub-package.
"""
