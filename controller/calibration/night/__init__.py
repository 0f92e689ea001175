"""Planned nights: the planner's geometries for each heliostat, the candidates it chooses from,
the passes run as campaigns one lamp at a time, lamp changes without a stray beam, the planned
night itself and the process pool the per-heliostat work is shared over.

May import every other calibration sub-package except reprocessing.
"""
