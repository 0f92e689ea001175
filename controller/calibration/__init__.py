"""Calibration orchestration: the measurement cycle of one heliostat, campaigns, planned nights,
several beams on a target, archive reprocessing and the records they make.

By subject, from the bottom up (each sub-package imports only those before it; docs/architecture.md
has the map):

* :mod:`~controller.calibration.records` — the record types a calibration creates;
* :mod:`~controller.calibration.cycle` — one heliostat's measurement cycle (the state machine)
  and the model update after its run;
* :mod:`~controller.calibration.beams` — several beams on one target (slots, shared capture,
  identity);
* :mod:`~controller.calibration.campaign` — the field and a queue of cycles on it, targets in
  parallel, lamp changes, lights out;
* :mod:`~controller.calibration.night` — planned nights: the planner, passes, the field's refit
  and daytime prediction over a process pool;
* :mod:`~controller.calibration.reprocess` — re-analysing the frame archive on Dask.

Orchestration imports the wire, the device drivers, the pure domain (and its ``*_io``
modules) and ``controller.io``; never the interfaces (commands, storage, reports, console).
"""
