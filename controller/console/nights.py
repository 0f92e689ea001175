"""A planned night started from the console: the CLI's night
(:class:`controller.calibration.night.planned.PlannedNight`, as ``heliocal campaign night`` runs it) in
a background thread, followed through its progress and published as ``night`` events.

What the page shows: tonight's night (index and name), the pass running and the lamp lit,
geometries measured of those planned, the field's predicted daytime error as it improves, the
night's log, its outcome and the geometries flagged after failing on two nights (not planned
until cleared). Start takes the database's campaign lock like the CLI; stop parks
every beam (each pass's campaign parks its own), leaves every lamp off (a lamp panel) and
records the night ``interrupted`` (start it again to resume).
"""

from __future__ import annotations

import threading
import time

from controller.calibration.night.planned import PlannedNight, tonight
from controller.console.backend import Conflict, Console
from controller.errors import HeliocalError
from controller.storage.nights import NightBook

LOG_LINES = 40  # progress lines kept for the page


class NightControl:
    """Start / stop one planned night at a time; :meth:`snapshot` for the page."""

    def __init__(self, console: Console) -> None:
        self.c = console
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._night: PlannedNight | None = None
        self.log: list[str] = []
        self.outcome: dict | None = None
        self.started: float | None = None
        # Geometries that failed on two nights: not planned until cleared (heliocal campaign flags).
        self.flagged: list[dict] = NightBook(console.store).flagged(console.ids)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, ids: list[str] | None = None) -> dict:
        c = self.c
        ids = c.heliostats_for("night", ids)
        with self._lock:
            c.take_over()
            book = NightBook(c.store)
            name, index = tonight(book, book.base_name() or c.cfg.site.name)
            if c.hooks.set_night is not None:
                c.hooks.set_night(index)
            night = PlannedNight(c.field, book, name, index, heliostat_ids=ids, progress=self._progress)
            self._night, self.log, self.outcome, self.started = night, [], None, time.monotonic()
            self._thread = threading.Thread(target=self._run, args=(night,), name="console-night",
                                            daemon=True)
            self._thread.start()
        self._publish("started")
        return self.snapshot()

    def _run(self, night: PlannedNight) -> None:
        try:
            self.outcome = night.run().to_json()
            self.flagged = self.outcome["flagged"]
        except HeliocalError as exc:
            self.outcome = {"status": "error", "cause": str(exc)}
        except Exception as exc:  # the night recorded what it could; the page must say why
            self.outcome = {"status": "aborted", "cause": f"{type(exc).__name__}: {exc}"}
        finally:
            self._thread = None
            self.c.release_lock_if_idle()
            self._publish("finished")

    def stop(self) -> dict:
        if not self.running or self._night is None:
            raise Conflict("no night is running")
        self._night.request_stop()
        self._publish("stopping")
        return self.snapshot()

    def shutdown(self, timeout_s: float = 60.0) -> None:
        """Console shutdown: stop a running night (beams parked) and wait for it."""
        t = self._thread
        if t is not None and self._night is not None:
            self._night.request_stop()
            t.join(timeout_s)

    def _progress(self, text: str) -> None:
        with self._lock:
            self.log = (self.log + [text])[-LOG_LINES:]
        self._publish("progress")

    def snapshot(self) -> dict:
        n = self._night
        return {"running": self.running, **(n.snapshot() if n is not None else {"name": None}),
                "elapsed_s": None if self.started is None else time.monotonic() - self.started,
                "log": list(self.log), "outcome": self.outcome, "flagged": self.flagged}

    def _publish(self, what: str) -> None:
        self.c.bus.publish("night", {"what": what, "snapshot": self.snapshot()})
