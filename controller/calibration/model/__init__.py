"""Tracking models after measuring: the update after a run (every measurement, aged, drifting
joints), the whole field refitted at once, and daytime tracking with a fitted model.

May import :mod:`~controller.calibration.records` and the pure domain
(:mod:`controller.geometry.model`); never the cycle, campaign, night or reprocessing.
"""
