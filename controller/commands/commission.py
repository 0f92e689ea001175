"""``heliocal commission --config C --heliostat H``: commissioning steps for one heliostat.

Without step flags it asks for steps interactively. Each step also has a flag, so scripts can
drive it; flags run in this order: ``--status``, ``--move AZ EL``, ``--aim``, ``--jog-az/--jog-el``,
``--capture PNG``, ``--store-reference LABEL --library LIB``, ``--verify``, ``--park``.
The camera is the configuration's ``camera.driver`` (gige, file; opened as ``campaign run``
opens it, only for the steps that look: capture, reference, verify, and the prompt),
``--camera-manifest M`` (recorded pairs) or ``--simulate`` (embedded simulated plant, one
heliostat; its firmware starts at stow). See docs/commissioning.md.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from controller.commands._numbers import SEED, STEPS
from controller.commands.common import add_config_option, add_json_option, check_camera, print_json
from controller.errors import HeliocalError, InputError

HELP = """steps:
  s | status                 drive status
  m AZ EL | move AZ EL       absolute move (steps), wait
  a | aim                    park at standby, then aim at the target centre
  j dAZ dEL | jog dAZ dEL    relative move (steps), wait
  c FILE.png | capture FILE  capture a pair, merge, analyse, write a PNG preview
  r LABEL | reference LABEL  store the last frame as reference case LABEL in --library
  v | verify                 capture and score the pointing error
  p | park                   move to the standby point
  q | quit"""
LOOKS = ("capture", "reference", "verify")  # the steps that use the camera


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "commission",
        help="commissioning steps for one heliostat",
        description=__doc__.splitlines()[0],
        epilog=HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_config_option(p)
    p.add_argument("--heliostat", required=True, metavar="H", help="heliostat id")
    p.add_argument("--status", action="store_true", help="print the drive status")
    p.add_argument("--move", nargs=2, type=STEPS, metavar=("AZ", "EL"), help="absolute move in steps")
    p.add_argument("--aim", action="store_true", help="approach from standby and aim at the target centre")
    p.add_argument("--jog-az", type=STEPS, default=0, metavar="STEPS", help="jog azimuth by STEPS")
    p.add_argument("--jog-el", type=STEPS, default=0, metavar="STEPS", help="jog elevation by STEPS")
    p.add_argument("--capture", metavar="PNG", help="capture a frame pair and write the HDR frame as PNG")
    p.add_argument("--store-reference", metavar="LABEL", help="store the frame as reference case LABEL")
    p.add_argument("--library", metavar="LIB", help="error library YAML for --store-reference / matching")
    p.add_argument("--verify", action="store_true", help="capture and score the pointing error")
    p.add_argument("--park", action="store_true", help="move to the standby point")
    p.add_argument("--camera-manifest", metavar="FILE", help="replay frame pairs (FileCamera)")
    p.add_argument("--simulate", action="store_true", help="use the embedded simulated plant")
    p.add_argument("--seed", type=SEED, default=0, help="simulation seed (with --simulate; default 0)")
    p.add_argument("--run-dir", default=None, metavar="DIR", help="simulation run directory (ptys)")
    p.add_argument("--leave-in-place", action="store_true",
                   help="do not park at standby when the session ends (by default every exit parks a "
                        "heliostat this session moved: normal end, error, Ctrl-C, SIGTERM)")
    add_json_option(p)
    p.set_defaults(func=run)


def _steps(args) -> list[tuple[str, tuple]]:
    steps: list[tuple[str, tuple]] = []
    if args.status:
        steps.append(("status", ()))
    if args.move:
        steps.append(("move", tuple(args.move)))
    if args.aim:
        steps.append(("aim", ()))
    if args.jog_az or args.jog_el:
        steps.append(("jog", (args.jog_az, args.jog_el)))
    if args.capture:
        steps.append(("capture", (args.capture,)))
    if args.store_reference:
        if not args.library:
            raise InputError("--store-reference needs --library LIB.yaml")
        steps.append(("reference", (args.store_reference,)))
    if args.verify:
        steps.append(("verify", ()))
    if args.park:
        steps.append(("park", ()))
    return steps


def run(args: argparse.Namespace) -> int:
    from controller.config import load_config

    cfg = load_config(args.config)
    cfg.heliostat(args.heliostat)
    steps = _steps(args)
    # Steps that only move or read the drive need no camera; the others open the configured one.
    looks = not steps or any(name in LOOKS for name, _ in steps)
    check_camera(cfg, args, "commission", needed=looks)
    from controller.recognition.library_io import load_library_if_present

    library = load_library_if_present(args.library)
    if args.simulate:
        return _with_simulated(cfg, args, steps, library)
    from contextlib import ExitStack, closing

    from controller.devices.drive import DriveLimits
    from controller.devices.factory import LinkPool, open_camera
    from controller.devices.lamp_panel import fiducial_hook

    h = cfg.heliostat(args.heliostat)
    with LinkPool() as pool, ExitStack() as stack:
        camera = None
        if looks:
            camera = stack.enter_context(closing(open_camera(cfg.camera, args.camera_manifest)))
        drive = pool.drive(h.link, DriveLimits.from_axes(h.axes))
        return _session(cfg, args, steps, drive, camera, library, fiducial_hook(cfg) if looks else None)


def _with_simulated(cfg, args, steps, library) -> int:
    from controller.commands.simulated import run_directory, simulated_plant
    from controller.devices.drive import DriveLimits
    from controller.devices.factory import LinkPool

    with run_directory(args.run_dir, "heliocal-commission-") as run_dir, \
            simulated_plant(args.config, run_dir, [args.heliostat], seed=args.seed) as plant:
        pcfg = plant.start()
        h = pcfg.heliostat(args.heliostat)
        with LinkPool() as pool:
            drive = pool.drive(h.link, DriveLimits.from_axes(h.axes))
            return _session(pcfg, args, steps, drive, plant.camera, library, plant.set_fiducials)


def _do(c, name: str, params: tuple, args) -> dict:
    if name == "status":
        return c.status()
    if name == "move":
        return c.move(*params)
    if name == "aim":
        return c.aim()
    if name == "jog":
        return c.jog(*params)
    if name == "park":
        return c.park()
    if name == "capture":
        cap = c.capture()
        c.save_png(cap.hdr, params[0])
        out = cap.to_json(c.pointing.aim_point, c.pointing.heliostat_pos)
        out["png"] = params[0]
        return out
    if name == "reference":
        if not args.library:
            raise InputError("storing a reference case needs --library LIB.yaml")
        return c.store_reference(params[0], args.library)
    if name == "verify":
        return c.verify()
    raise InputError(f"unknown step {name!r}")


def _session(cfg, args, steps, drive, camera, library, fiducial_lamps=None) -> int:
    from controller.calibration.cycle.commissioning import Commissioning

    c = Commissioning(cfg, args.heliostat, drive, camera, library=library, fiducial_lamps=fiducial_lamps)
    results: dict = {}
    try:
        if not steps:
            return _interactive(c, args)
        for name, params in steps:
            results[name] = _do(c, name, params, args)
    finally:
        # Whatever ends the session, the beam is not left where the session put it.
        if c.needs_parking and not args.leave_in_place:
            results["exit"] = done = c.make_safe()
            print(f"heliocal commission: {args.heliostat} {_said(done)}", file=sys.stderr)
        elif c.needs_parking:
            print(f"heliocal commission: {args.heliostat} left in place (--leave-in-place)", file=sys.stderr)
    if args.json:
        print_json({"heliostat": args.heliostat, "ok": True, "steps": results})
    else:
        for name, res in results.items():
            print(f"{name}: {human(name, res)}")
    return 0


def _drive_text(r: dict) -> str:
    state = "moving" if r.get("moving") else ("in position" if r.get("in_position") else "stopped")
    faults = ", ".join(r.get("faults") or []) or "no faults"
    return f"az {r['az_steps']} el {r['el_steps']} steps, {state}, {faults}"


def human(step: str, r: dict) -> str:
    """One step's result in words (the --json output keeps the data)."""
    if step in ("status", "move", "jog", "aim", "park"):
        return _drive_text(r)
    if step == "exit":
        return _said(r)
    if step == "capture":
        if not r.get("beam"):
            return f"no beam: {r['problem']}"
        x, y = r["centroid_px"]
        return (f"beam centroid at x {x:.1f}, y {y:.1f} px, {r['error_mrad']:.2f} mrad from the aim point, "
                f"peak {r['peak']:.4g}; preview {r['png']}")
    if step == "verify":
        if not r.get("beam"):
            return f"no beam: {r['problem']}"
        verdict = "within" if r["ok"] else "OUTSIDE"
        text = (f"pointing error {r['error_mrad']:.3f} mrad, {verdict} the tolerance of "
                f"{r['tolerance_mrad']:g} mrad")
        if "match" in r:
            text += f"; looks like {r['match']['label']} (distance {r['match']['distance']:.3g})"
        return text
    if step == "reference":
        return f"stored {r['label']!r} as {r['image']} ({r['entries']} entries in {r['library']})"
    return str(r)


def _said(done: dict) -> str:
    if done["action"] == "parked":
        return f"parked at standby (az {done['az_steps']}, el {done['el_steps']})"
    if done["action"] == "stopped":
        return f"stopped where it is (az {done['az_steps']}, el {done['el_steps']}): {done['reason']}"
    return f"could NOT be made safe: {done['reason']}; check the heliostat"


# name -> (usage, argument kinds); every prompt command is checked against it before it runs.
_USAGE = {
    "status": ("status", ()),
    "move": ("move AZ EL   (motor steps, integers)", (int, int)),
    "aim": ("aim", ()),
    "jog": ("jog dAZ dEL   (motor steps, integers)", (int, int)),
    "capture": ("capture FILE.png", (str,)),
    "reference": ("reference LABEL", (str,)),
    "verify": ("verify", ()),
    "park": ("park", ()),
}


def parse_prompt(line: str) -> tuple[str, tuple] | None:
    """One prompt line as (command, arguments); None for an empty line. InputError carries the
    usage of the command when its arguments do not fit."""
    try:
        words = shlex.split(line)
    except ValueError as exc:
        raise InputError(f"cannot read the line: {exc}") from None
    if not words:
        return None
    cmd = _ALIASES.get(words[0], words[0])
    if cmd in ("q", "quit", "exit", "h", "help", "?"):
        return cmd, ()
    if cmd not in _USAGE:
        raise InputError(f"unknown command {words[0]!r}; 'h' lists the commands")
    usage, kinds = _USAGE[cmd]
    args = words[1:]
    if len(args) != len(kinds):
        raise InputError(f"usage: {usage}")
    try:
        return cmd, tuple(kind(a) for kind, a in zip(kinds, args, strict=True))
    except ValueError:
        raise InputError(f"usage: {usage}") from None


_ALIASES = {
    "s": "status",
    "m": "move",
    "a": "aim",
    "j": "jog",
    "c": "capture",
    "r": "reference",
    "v": "verify",
    "p": "park",
}


def _interactive(c, args) -> int:
    print(f"commissioning {args.heliostat}; 'h' for help", file=sys.stderr)
    while True:
        try:
            line = input("commission> ")
        except EOFError:
            return 0
        try:
            parsed = parse_prompt(line)
            if parsed is None:
                continue
            cmd, params = parsed
            if cmd in ("q", "quit", "exit"):
                return 0
            if cmd in ("h", "help", "?"):
                print(HELP)
                continue
            if cmd in ("move", "jog", "aim", "park"):  # motion takes a while: say it started
                c.needs_parking = True  # from here on, an interruption must park
                print(f"{cmd} {' '.join(map(str, params))} …".replace("  ", " "), file=sys.stderr, flush=True)
            print(human(cmd, _do(c, cmd, params, args)))
        except HeliocalError as exc:
            print(f"error: {exc}")
