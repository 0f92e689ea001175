"""``heliocal lamps``: commission the lamp panel of the configuration's ``lamps:`` section.

Contract (docs/lamps.md, scripts depend on it)::

    heliocal lamps --config C [status | on LAMP | off LAMP | all-off] [--json]

``status`` (the default) reads every channel: what the panel was told (``commanded``; null
where the driver cannot tell) and what the lamp confirms (``lit``). ``on LAMP`` / ``off LAMP``
switch that one channel only — the other lamps stay as they are — and wait up to
``lamps.confirm_timeout_s`` for its confirmation. ``all-off`` switches every channel off and
waits until all confirm dark. JSON: ``{"ok": true, "action": ..., "panel": ..., "lamps":
[{"channel", "commanded", "lit"}, ...]}`` (plus ``"channel"`` for on/off). Exit 0 done, 1 the
panel failed or a lamp did not confirm (the line names it), 2 bad input (no ``lamps:``
section, an unknown LAMP), 130 interrupted (Ctrl-C, SIGTERM) — after ``on``/``off`` switched
that channel off again and ``all-off`` every channel, confirmed dark: an interrupted command
never leaves a lamp on (1 when the panel cannot confirm it).
"""

from __future__ import annotations

import signal
import sys
import threading

from controller.commands.common import add_config_option, add_json_option, print_json
from controller.errors import InputError

ACTIONS = ("status", "on", "off", "all-off")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "lamps", help="read or switch the lamp panel (commissioning)", description=__doc__.split("\n\n")[0],
        epilog="on LAMP switches only that lamp (the others stay as they are) and waits for its "
               "confirmation; all-off switches every channel off and waits until all are dark")
    add_config_option(p)
    p.add_argument("action", nargs="?", default="status", choices=ACTIONS,
                   help="status (default), on LAMP, off LAMP or all-off")
    p.add_argument("lamp", nargs="?", metavar="LAMP",
                   help="the channel of on/off: a lamp id or fiducials:<target id> (lamps.channels)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.config import load_config
    from controller.devices.lamp_drivers import open_lamp_panel
    from controller.devices.lamp_panel import lights_out, set_and_confirm
    from controller.devices.plant_time import WALL

    cfg = load_config(args.config)
    if args.action in ("on", "off") and not args.lamp:
        raise InputError(f"lamps {args.action}: name the LAMP to switch")
    if args.action not in ("on", "off") and args.lamp:
        raise InputError(f"lamps {args.action}: takes no LAMP (got {args.lamp!r})")
    lamps = cfg.lamps
    if lamps is None:
        raise InputError(f"{args.config}: no lamps: section (the lamp panel, docs/lamps.md)")
    if args.lamp and args.lamp not in lamps.channels:
        raise InputError(f"{args.config}: no lamp channel {args.lamp!r} in lamps.channels "
                         f"(known: {', '.join(lamps.channels)})")
    timeout_s = lamps.confirm_timeout_s
    with open_lamp_panel(lamps) as panel:
        try:
            if args.action in ("on", "off"):
                set_and_confirm(panel, args.lamp, args.action == "on", time=WALL, timeout_s=timeout_s)
            elif args.action == "all-off":
                lights_out(panel, time=WALL, timeout_s=timeout_s)
            states = panel.states()
        except KeyboardInterrupt:
            if args.action == "status":
                raise
            return _interrupted(args, panel, timeout_s)
    out = {"ok": True, "action": args.action, "panel": panel.name}
    if args.lamp:
        out["channel"] = args.lamp
    out["lamps"] = [s.to_json() for s in states]
    if args.json:
        print_json(out)
        return 0
    for s in states:
        told = "?" if s.commanded is None else ("on" if s.commanded else "off")
        print(f"{s.channel:<28} {'lit' if s.lit else 'dark':<5} (commanded {told})")
    return 0


def _interrupted(args, panel, timeout_s: float) -> int:
    """Ctrl-C or SIGTERM while switching: the channel (``all-off``: every channel) off again and
    confirmed dark, a second signal ignored meanwhile (the switching is bounded by the panel's
    timeouts); 130, or LampError (exit 1) when the panel cannot confirm it."""
    from controller.devices.lamp_panel import LampError, lights_out, set_and_confirm
    from controller.devices.plant_time import WALL

    main = threading.current_thread() is threading.main_thread()
    held = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    what = f"lamp {args.lamp}" if args.lamp else "every lamp"
    panel.close()  # a request cut short may still be answered: a new connection for these
    try:
        if args.lamp:
            set_and_confirm(panel, args.lamp, False, time=WALL, timeout_s=timeout_s)
        else:
            lights_out(panel, time=WALL, timeout_s=timeout_s)
    except LampError as exc:
        raise LampError(f"interrupted; {what} could not be confirmed off: {exc}") from None
    finally:
        for s, handler in held.items():
            signal.signal(s, handler)
    line = f"interrupted; {what} switched off and confirmed dark"
    if args.json:
        print_json({"ok": False, "error": line})
    else:
        print(f"heliocal lamps: {line}", file=sys.stderr)
    return 130
