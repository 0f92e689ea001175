"""The console's commands on one heliostat: the steps of ``heliocal commission`` as a guided
page (connect, home, limits check, first light on target, first measurement, first
correction, record) plus jog, move, park, stow, stop and clear-fault.

Every step runs inside :meth:`Console.command` (safety rules there) through the
:class:`~controller.calibration.cycle.commissioning.Commissioning` session of the heliostat, so the
moves are those of the CLI: ``Drive.move_and_wait`` with the soft limits checked before sending.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from controller.console.backend import Conflict, Console, only_keys, read_limits
from controller.console.events import plain
from controller.errors import HeliocalError, InputError, LimitError
from controller.io.images import write_atomic
from controller.io.json_files import dumps_json

# step -> (moves the heliostat, path keeps the beam off the target, parameter names)
STEPS: dict[str, tuple[bool, bool, tuple[str, ...]]] = {
    "connect": (False, False, ()),
    "home": (True, False, ()),
    "limits": (False, False, ()),
    "aim": (True, False, ()),
    "capture": (False, False, ()),
    "correct": (True, False, ()),
    "verify": (False, False, ()),
    "record": (False, False, ()),
    "move": (True, False, ("az_steps", "el_steps")),
    "jog": (True, False, ("az_steps", "el_steps")),
    "park": (True, True, ()),
    "stow": (True, True, ()),
    "stop": (False, False, ()),
    "clear_fault": (False, False, ()),
}


def run_step(console: Console, hid: str, step: str, body: dict) -> dict:
    """Run ``step`` on ``hid`` with the JSON ``body``; returns the step's result (JSON-able)."""
    if step not in STEPS:
        raise InputError(f"unknown step {step!r}; one of {', '.join(STEPS)}")
    moves, safe, names = STEPS[step]
    only_keys(body, names + (("label",) if step == "record" else ()), step)
    params = [_int(body, n) for n in names]
    with console.command(hid, moves=moves, beam_safe=safe) as c:
        before = c.needs_parking
        try:
            extra = {"body": body} if step == "record" else {}
            result = plain(_ACTIONS[step](console, c, *params, **extra))
        except HeliocalError as exc:
            if exc.outcome == "not_executed":  # refused before sending or by the firmware: nothing moved
                c.needs_parking = before
            raise
    return console.log(hid, step, result)


def _int(body: dict, name: str) -> int:
    v = body.get(name)
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(f"{name} must be an integer number of motor steps, got {v!r}")
    return v


def _connect(console: Console, c) -> dict:
    info = c.drive.info()
    return {"status": c.status(), "firmware": {"version": info.firmware_version,
                                               "protocol": info.protocol_version, "axes": info.axes},
            "link": console.cfg.heliostat(c.h.id).link.kind}


def _home(console: Console, c) -> dict:
    if c.needs_parking:
        raise Conflict(f"{c.h.id}: park first; homing from here could sweep the beam across the target")
    c.drive.home()
    return c.drive.wait_in_position(console.move_timeout_s).to_json()


def _limits(console: Console, c) -> dict:
    """Configuration vs firmware soft limits, and the controller's own check one step outside."""
    out = read_limits(console, c.h.id)
    az_max = out["config"]["az"][1]
    st = c.drive.status()
    try:
        c.drive.limits.check(az_max + 1, st.el_steps)
        out["controller_check"] = "MISSING: a target outside the soft limits was accepted"
    except LimitError as exc:
        out["controller_check"] = f"refused before sending: {exc}"
    return out


def _capture(console: Console, c) -> dict:
    cap = c.capture()
    return cap.to_json(c.pointing.aim_point, c.pointing.heliostat_pos)


def _correct(console: Console, c) -> dict:
    """The fine correction of the last measurement (centroid offset through the Jacobian of
    the aim), applied as a jog."""
    cap = c.last
    if cap is None or cap.observation is None:
        raise InputError("no measurement with a beam yet: run 'first measurement' (capture) first")
    st = c.drive.status()
    offset = np.asarray(cap.observation.centroid_enu, float) - c.pointing.aim_point
    step = c.pointing.fine_correction(st.az_steps, st.el_steps, offset)
    status = c.jog(step.daz_steps, step.del_steps)
    return {"correction": {"daz_deg": step.daz_deg, "del_deg": step.del_deg, "daz_steps": step.daz_steps,
                           "del_steps": step.del_steps}, "status": status}


def _record(console: Console, c, body: dict) -> dict:
    """The session's steps as one JSON record beside the database (and, with a label and the
    console's --library, the last frame as a reference case)."""
    hid = c.h.id
    label = body.get("label") or None
    out: dict = {}
    if label:
        if not console.library_path:
            raise InputError("storing a reference case needs the console started with --library LIB.yaml")
        out["reference"] = c.store_reference(str(label), console.library_path)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    path = console.store.path.parent / "commissioning" / f"{hid}-{stamp}.json"
    record = {"heliostat": hid, "steps": console.logs[hid], **out}
    write_atomic(path, lambda t: t.write_text(dumps_json(plain(record), indent=1), encoding="utf-8"))
    return {"record": str(path), "steps": len(console.logs[hid]), **out}


def _stow(console: Console, c) -> dict:
    """Park at standby along the beam-safe path first, then the firmware's stow."""
    c.park()
    c.drive.stow()
    return c.drive.wait_in_position(console.move_timeout_s).to_json()


def _stop(console: Console, c) -> dict:
    c.drive.stop()
    return c.status()


def _clear(console: Console, c) -> dict:
    c.drive.clear_fault()
    return c.status()


_ACTIONS: dict[str, Callable[..., dict]] = {
    "connect": _connect,
    "home": _home,
    "limits": _limits,
    "aim": lambda console, c: c.aim(),
    "capture": _capture,
    "correct": _correct,
    "verify": lambda console, c: c.verify(),
    "record": _record,
    "move": lambda console, c, az, el: c.move(az, el),
    "jog": lambda console, c, daz, dele: c.jog(daz, dele),
    "park": lambda console, c: c.park(),
    "stow": _stow,
    "stop": _stop,
    "clear_fault": _clear,
}
