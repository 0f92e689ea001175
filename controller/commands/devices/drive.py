"""``heliocal drive``: talk to one heliostat drive controller over any link.

Contract (docs/serial-link.md, scripts depend on it)::

    heliocal drive --serial PATH --unit N [--baud B] [--timeout S] [--retries K] status --json
        -> {"unit": N, "az_steps": a, "el_steps": e, "moving": false, "in_position": true, "faults": []}
    heliocal drive --serial PATH --unit N move --az-steps A --el-steps E [--wait] --json
    heliocal drive --serial PATH --unit N jog --az-steps dA --el-steps dE [--wait] --json
        -> {"ok": true, "az_steps": a, "el_steps": e, "retries": r}

``--modbus-tcp HOST:PORT`` or ``--modbus-rtu PATH`` replace ``--serial``; the JSON is the same.
Targets are checked against the configuration's soft limits *and* the firmware's (GET_LIMITS)
before anything is sent; out of range exits 2. Failures print ``{"ok": false, "error": ...}``.
"""

from __future__ import annotations

import argparse
import math
import sys

from controller.commands._numbers import STEPS, Number
from controller.commands.common import DEFAULT_CONFIG, add_json_option, print_json
from controller.commands.devices._links import add_link_options, heliostat_for, link_model, load_plant
from controller.devices.drive import AxisLimits, DriveError, DriveLimits, MoveResult
from controller.errors import DeviceError, HeliocalError, InputError

_WIDE = DriveLimits(AxisLimits(-(2**31), 2**31 - 1), AxisLimits(-(2**31), 2**31 - 1))


def register(subparsers) -> None:
    p = subparsers.add_parser("drive", help="status, move or jog one heliostat drive",
                              description=__doc__.split("\n\n")[0])
    add_link_options(p, "--serial")
    p.add_argument("--unit", type=Number(1, 247, integer=True), required=True,
                   help="bus address / Modbus unit id (1..247)")
    p.add_argument("--baud", type=Number(300, 4_000_000, integer=True), default=115200,
                   help="serial baud rate (default 115200)")
    p.add_argument("--timeout", type=Number(0, 60, lo_open=True), default=0.2, metavar="S",
                   help="reply timeout per attempt, s (default 0.2)")
    p.add_argument("--retries", type=Number(0, 100, integer=True), default=3, metavar="K",
                   help="retransmissions after the first attempt (default 3)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help=f"plant configuration for the soft limits (default {DEFAULT_CONFIG} if present)")
    # --json belongs after the action (contract); accepted before it too.
    p.add_argument("--json", dest="json_first", action="store_true", help=argparse.SUPPRESS)
    sub = p.add_subparsers(dest="drive_command", metavar="ACTION", required=True)
    for name, help_text in (("status", "read positions, motion and faults"),
                            ("info", "firmware version and hard ranges"),
                            ("limits", "soft limits: configuration and firmware"),
                            ("stop", "stop both axes"), ("home", "move to the home position"),
                            ("stow", "move to the stow position"),
                            ("clear-fault", "clear latched faults")):
        add_json_option(sub.add_parser(name, help=help_text))
    for name, help_text, unit in (("move", "absolute move, motor steps", "steps"),
                                  ("jog", "relative move, motor steps", "steps to add")):
        a = sub.add_parser(name, help=help_text)
        a.add_argument("--az-steps", type=STEPS, required=True, help=f"azimuth {unit}")
        a.add_argument("--el-steps", type=STEPS, required=True, help=f"elevation {unit}")
        a.add_argument("--wait", action="store_true", help="wait until in position and verify it")
        a.add_argument("--wait-timeout", type=Number(0, 86400, lo_open=True), default=120.0, metavar="S",
                       help="give up waiting after S seconds (default 120)")
        a.add_argument("--leave-in-place", action="store_true",
                       help="on Ctrl-C/SIGTERM while waiting, do not stop the axes (default: stop them)")
        add_json_option(a)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.devices.factory import LinkPool

    args.json = args.json or args.json_first
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= 60):
        raise InputError(f"--timeout must be in (0, 60] s, got {args.timeout}")
    if not 0 <= args.retries <= 100:
        raise InputError(f"--retries must be in 0..100, got {args.retries}")
    wait_s = getattr(args, "wait_timeout", None)
    if wait_s is not None and not (math.isfinite(wait_s) and 0 < wait_s <= 86400):
        raise InputError(f"--wait-timeout must be in (0, 86400] s, got {wait_s}")
    link = link_model(args, args.unit, args.baud)
    motion = args.drive_command in ("move", "jog")
    plant = load_plant(args.config, required=False)
    heliostat = None
    if plant is not None:
        heliostat, matched = heliostat_for(plant, link)
        cfg_limits = DriveLimits.from_axes(heliostat.axes)
        source = f"configuration heliostat {heliostat.id}" + ("" if matched else " (first heliostat)")
    else:
        cfg_limits, source = None, None
    pool = LinkPool(timeout_s=args.timeout, retries=args.retries)
    try:
        drive = pool.drive(link, cfg_limits or _WIDE)
        result = _act(args, drive, cfg_limits, source) if motion else _query(args, drive, cfg_limits,
                                                                               source)
    except HeliocalError:
        raise
    except Exception as exc:  # the CLI boundary: any driver failure becomes one clean line
        raise DeviceError(f"{type(exc).__name__}: {exc}") from None
    finally:
        pool.close()
    if args.json:
        print_json(result)
    else:
        print(" ".join(f"{k}={v}" for k, v in result.items()))
    return 0


def _act(args, drive, cfg_limits: DriveLimits | None, source: str | None) -> dict:
    fw_limits = drive.get_limits()
    status = drive.status() if args.drive_command == "jog" else None
    if status is not None:
        target = (status.az_target + args.az_steps, status.el_target + args.el_steps)
        what = "jog result"
    else:
        target = (args.az_steps, args.el_steps)
        what = "target"
    # Both sets of limits are checked before anything that moves is sent.
    if cfg_limits is not None:
        cfg_limits.check(*target, f"{what} ({source})")
    if fw_limits is not None:
        fw_limits.check(*target, f"{what} (firmware)")
    drive.limits = _intersect(cfg_limits, fw_limits)
    # A signal may arrive as soon as the command is on its way (the axes may already move): with
    # --wait, from then on it stops them, not only once the wait has begun.
    try:
        if status is not None:
            drive.jog(args.az_steps, args.el_steps, from_status=status)
            target = drive.last_targets or target
        else:
            drive.move_abs(*target)
        az, el = target
        if args.wait:
            try:
                st = drive.wait_in_position(args.wait_timeout, expect=target)
            except DriveError as exc:
                # The command itself was acknowledged: whatever went wrong while waiting, it was
                # executed, and sending it again would move the axes twice.
                exc.outcome = "executed"
                raise
            az, el = st.az_steps, st.el_steps
    except KeyboardInterrupt:
        if args.wait:
            _interrupted(args, drive)
        raise
    return MoveResult(True, az, el, retries=drive.retries_used).to_json()


def _interrupted(args, drive) -> None:
    """Ctrl-C / SIGTERM while waiting: the axes would go on moving; stop them (unless
    --leave-in-place) and say where they are."""
    if args.leave_in_place:
        print(f"heliocal drive: unit {drive.unit} left moving (--leave-in-place)", file=sys.stderr)
        return
    try:
        drive.stop()
        st = drive.status()
        print(f"heliocal drive: interrupted; unit {drive.unit} axes stopped at az {st.az_steps}, "
              f"el {st.el_steps}", file=sys.stderr)
    except HeliocalError as exc:
        print(f"heliocal drive: interrupted; STOP FAILED for unit {drive.unit} ({exc}): the axes may "
              "still be moving", file=sys.stderr)


def _query(args, drive, cfg_limits: DriveLimits | None, source: str | None) -> dict:
    cmd = args.drive_command
    if cmd == "status":
        return drive.status().to_json()
    if cmd == "info":
        info = drive.info()
        return {"unit": drive.unit, "firmware_version": info.firmware_version,
                "protocol_version": info.protocol_version, "axes": info.axes,
                "hard_limits": _limits_json(info.hard_limits)}
    if cmd == "limits":
        fw = drive.get_limits()
        return {"unit": drive.unit, "config": _limits_json(cfg_limits), "config_source": source,
                "firmware": _limits_json(fw)}
    {"stop": drive.stop, "home": drive.home, "stow": drive.stow,
     "clear-fault": drive.clear_fault}[cmd]()
    return {"ok": True, "unit": drive.unit, "action": cmd, "retries": drive.retries_used}


def _limits_json(lim: DriveLimits | None) -> dict | None:
    if lim is None:
        return None
    return {"az": [lim.az.min_steps, lim.az.max_steps], "el": [lim.el.min_steps, lim.el.max_steps]}


def _intersect(a: DriveLimits | None, b: DriveLimits | None) -> DriveLimits:
    if a is None or b is None:
        return a or b or _WIDE

    def one(x: AxisLimits, y: AxisLimits) -> AxisLimits:
        return AxisLimits(max(x.min_steps, y.min_steps), min(x.max_steps, y.max_steps))

    return DriveLimits(one(a.az, b.az), one(a.el, b.el))
