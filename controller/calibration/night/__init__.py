"""Planned nights: the planner's geometries for each heliostat, the candidates it chooses from,
the passes run as campaigns one lamp at a time, the planned night itself, refitting the whole
field, daytime tracking with the fitted models, and the process pool the per-heliostat work is
shared over.

May import every calibration sub-package but reprocessing.
"""
