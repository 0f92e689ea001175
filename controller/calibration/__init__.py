"""Calibration orchestration: the measurement cycle of one heliostat, campaigns, planned nights,
several beams on a target, tracking-model updates, archive reprocessing and the records they make.

Sub-packages by subject (docs/architecture.md has the map):

* :mod:`~controller.calibration.cycle` — one heliostat's measurement cycle (the state machine);
* :mod:`~controller.calibration.campaign` — a queue of cycles on a field, targets in parallel;
* :mod:`~controller.calibration.night` — planned nights: the planner, passes, lamp changes;
* :mod:`~controller.calibration.beams` — several beams on one target (gate, slots, identity);
* :mod:`~controller.calibration.model` — tracking-model updates and daytime tracking;
* :mod:`~controller.calibration.reprocess` — re-analysing the frame archive on Dask;
* :mod:`~controller.calibration.records` — the records a calibration makes and its observers.

Orchestration imports the wire, the device drivers, the pure domain (and its ``*_io``
modules) and ``controller.io``; never the interfaces (commands, storage, reports, console).
"""
