"""Adversarial lamp cases (issue 45), three categories:

* ``lamp_programs``: ``heliocal lamps on|status`` with a ``lamps.driver: command`` program the
  system cannot run or that misbehaves (no ``#!`` line, other binary formats, an empty file,
  not executable, missing, a folder, a missing or non-executable interpreter, output that is
  not UTF-8, floods on stdout or stderr, a program that hangs, one whose child holds its
  output or survives the kill, one that leaves the group, one killed by a signal). Refused:
  exit 1, one line on stderr naming ``lamps.command``, within the timeout plus a margin, no
  process of it left running.
* ``lamp_panel_peers``: ``heliocal lamps status|on`` against a TCP peer that is not a Modbus
  lamp panel (``tests/devices/tcp_peers.py``: echo, garbage, HTTP, another function's answer,
  wrong byte count, bad padding, a trickle of bytes, a peer that closes, a banner). Refused:
  exit 1, one line naming the address, no lamp reported lit.
* ``night_lamp_failures``: a planned night on the simulated plant whose first lamp change
  meets a faulty panel (unreachable, a Modbus exception, an echo, garbage, lamps that never
  confirm dark, a switch program that fails, hangs, floods or cannot be executed), and a
  resumed night whose stored plan names a lamp no longer configured. Refused: one line, exit 1
  (2 for the stale plan), the night's record ``aborted`` with the cause, never ``running``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import socket
import struct
import sys
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from adversarial.tally import Tally  # noqa: E402
from tests.calibration.conftest import small_demo_data  # noqa: E402
from tests.devices.tcp_peers import KINDS, NotAPanel  # noqa: E402

TIMEOUT_S = 1.0  # the switch program's timeout and the panel's answer timeout in these cases


def _program_cases(folder: Path) -> dict[str, tuple[list[str], int]]:
    """name -> (the command's argv, file mode); each program written into ``folder``."""
    elf_other = b"\x7fELF\x02\x01\x01" + bytes(9) + struct.pack("<HHI", 2, 0xB7, 1) + bytes(40)
    texts: dict[str, tuple[bytes, int]] = {
        "no-shebang": (b"echo switched\n", 0o755),
        "pe-binary": (b"MZ\x90\x00\x03" + bytes(59), 0o755),
        "elf-aarch64": (elf_other, 0o755),
        "mach-o": (b"\xcf\xfa\xed\xfe\x07\x00\x00\x01" + bytes(56), 0o755),
        "empty-file": (b"", 0o755),
        "not-executable": (b"#!/bin/sh\nexit 0\n", 0o644),
        "missing-interpreter": (b"#!/nonexistent/bin/lampsh\nexit 0\n", 0o755),
        "interpreter-not-executable": (f"#!{folder / 'plain.txt'}\n".encode(), 0o755),
        "stderr-not-utf8": (b"#!/bin/sh\nprintf '\\377\\376\\033[31m\\200 down\\n' >&2\nexit 3\n", 0o755),
        "binary-status": (b"#!/bin/sh\nhead -c 3000 /dev/urandom\nexit 2\n", 0o755),
        "flood-stdout": (b"#!/bin/sh\nexec yes lamp-bench-flood\n", 0o755),
        "flood-stderr": (b"#!/bin/sh\nexec yes lamp-bench-flood >&2\n", 0o755),
        "one-huge-line": (b"#!/bin/sh\nhead -c 60000 /dev/zero | tr '\\0' x >&2\nexit 5\n", 0o755),
        "hangs": (b"#!/bin/sh\nsleep 317\n", 0o755),
        "closes-output-then-hangs": (b"#!/bin/sh\nexec >&- 2>&-\nsleep 317\n", 0o755),
        "child-holds-output-fails": (b"#!/bin/sh\nsleep 317 &\necho relay stuck >&2\nexit 4\n", 0o755),
        "child-ignores-term": (b"#!/bin/sh\n(trap '' TERM INT HUP; sleep 317) &\nsleep 317\n", 0o755),
        "child-leaves-group": (b"#!/bin/sh\nsetsid sleep 317 &\nsleep 0.05\nexit 6\n", 0o755),
        "killed-by-signal": (b"#!/bin/sh\nkill -9 $$\n", 0o755),
    }
    (folder / "plain.txt").write_text("not a program\n")
    cases = {}
    for name, (content, mode) in texts.items():
        p = folder / f"prog-{name}"
        p.write_bytes(content)
        p.chmod(mode)
        cases[name] = ([str(p)], mode)
    cases["missing"] = ([str(folder / "no-such-program")], 0)
    cases["folder"] = ([str(folder)], 0)
    return cases


def _config(folder: Path, name: str, lamps: dict) -> Path:
    """configs/demo.yaml with ``lamps`` as its lamps: section (a channel for each of its lamps),
    written to ``folder``."""
    data = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    ids = [s["id"] for s in data["light_sources"] if s["kind"] == "lamp"]
    data["lamps"] = {**lamps, "channels": {lamp: i for i, lamp in enumerate(ids)}}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _cli(argv: list[str]) -> tuple[int, str, str]:
    from controller.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def _left_running(folder: Path) -> list[int]:
    """Our processes still running a program of ``folder`` or its ``sleep 317`` children."""
    me, pids = os.getpid(), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ")
            with open(f"/proc/{pid}/stat") as f:
                zombie = f.read().rsplit(")", 1)[1].split()[0] == "Z"
        except OSError:
            continue
        if int(pid) != me and not zombie and (str(folder).encode() in cmd or cmd.strip() == b"sleep 317"):
            pids.append(int(pid))
    return pids


def _warm_up(folder: Path) -> None:
    """One good ``lamps status`` first, so that the cases' times and memory are the refusals'
    and not the imports'."""
    ok = folder / "ok-switch"
    ok.write_text("#!/bin/sh\n[ \"$1\" = status ] && exit 1\nexit 0\n")
    ok.chmod(0o755)
    config = _config(folder, "ok", {"driver": "command", "command": [str(ok)], "timeout_s": TIMEOUT_S})
    assert _cli(["lamps", "--config", str(config), "status"])[0] == 0


def lamp_programs(folder: Path) -> dict:
    _warm_up(folder)
    t = Tally()
    for name, (argv, _) in _program_cases(folder).items():
        config = _config(folder, f"program-{name}", {"driver": "command", "command": argv,
                                                      "timeout_s": TIMEOUT_S,
                                                      "confirm_timeout_s": 2.0})
        for action in (["on", "lamp-west"], ["status"]):
            before = set(_left_running(folder))  # not this case's

            def refused(o, before=before) -> bool:
                if not isinstance(o, tuple):
                    return False
                code, _, err = o
                lines = err.strip().splitlines()
                # The exit ended it: give the kernel a moment to remove the killed processes.
                deadline = time.monotonic() + 2.0
                while set(_left_running(folder)) - before and time.monotonic() < deadline:
                    time.sleep(0.01)
                return (code == 1 and len(lines) == 1 and "lamps.command" in lines[0]
                        and not set(_left_running(folder)) - before)
            t.case(f"{name} {' '.join(action)}",
                   lambda c=config, a=action: _cli(["lamps", "--config", str(c), *a]), refused)
    return t.report()


def lamp_panel_peers(folder: Path) -> dict:
    t = Tally()
    for kind in KINDS:
        with NotAPanel(kind) as peer:
            config = _config(folder, f"peer-{kind}", {"driver": "modbus-tcp", "host": "127.0.0.1",
                                                      "port": peer.port, "timeout_s": TIMEOUT_S / 4,
                                                      "confirm_timeout_s": 2.0})
            for action in (["status"], ["status", "--json"], ["on", "lamp-west"], ["all-off"]):
                def refused(o, p=peer.port, a=action) -> bool:
                    if not isinstance(o, tuple):
                        return False
                    code, out, err = o
                    said = out if "--json" in a else err
                    return (code == 1 and said.strip().count("\n") == 0 and f"127.0.0.1:{p}" in said
                            and '"lit": true' not in out and " lit " not in out)
                t.case(f"{kind} {' '.join(action)}",
                       lambda c=config, a=action: _cli(["lamps", "--config", str(c), *a]), refused)
    return t.report()


def night_lamp_failures(folder: Path) -> dict:
    """Each fault at a planned night's first lamp change, on one simulated plant."""
    from controller.calibration.campaign.field import PanelLamps
    from controller.calibration.night.planned import PlannedNight
    from controller.calibration.night.planner import Geometry, PlanItem
    from controller.commands.field import open_store
    from controller.commands.simulated import simulated_field, simulation_settings
    from controller.config import CommandLamps, load_config
    from controller.devices.lamp_drivers import open_lamp_panel
    from controller.errors import HeliocalError
    from controller.storage.nights import NightBook

    data = small_demo_data()
    config = folder / "night.yaml"
    config.write_text(yaml.safe_dump(data))
    (folder / "night-programs").mkdir()
    programs = {name: argv for name, (argv, _) in _program_cases(folder / "night-programs").items()}
    t = Tally()
    store = open_store(folder / "night.db")
    settings = simulation_settings(seed=5, clock_speedup=50.0)
    with simulated_field(load_config(config), str(config), store, folder / "sim", ["H02"], settings, night=1,
                         library=None) as fs:
        real = fs.plant.config.lamps
        channels = dict(real.channels)

        def command(argv: list[str]):
            return CommandLamps(driver="command", command=tuple(argv), channels=channels, timeout_s=TIMEOUT_S,
                                confirm_timeout_s=2.0)

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            free = s.getsockname()[1]
        faults = {"program-fails": lambda: command(programs["child-holds-output-fails"]),
                  "unreachable": lambda: real.model_copy(update={"port": free, "timeout_s": TIMEOUT_S / 4}),
                  "modbus-exception": lambda: real.model_copy(update={"unit": 9}),
                  "always-lit": lambda: command([str(_always_lit(folder))])}
        for name in ("no-shebang", "pe-binary", "not-executable", "missing", "stderr-not-utf8",
                     "flood-stdout", "hangs", "child-ignores-term", "killed-by-signal"):
            faults[name] = lambda n=name: command(programs[n])
        for kind in ("echo", "garbage", "http", "fc05"):
            faults[kind] = kind

        def night(name: str, section) -> object:
            peer = None
            if isinstance(section, str):
                peer = NotAPanel(section).__enter__()
                section = real.model_copy(update={"port": peer.port, "timeout_s": TIMEOUT_S / 4})
            lamps = PanelLamps(open_lamp_panel(section), fs.field.time, section.confirm_timeout_s)
            try:
                return PlannedNight(dataclasses.replace(fs.field, lamps=lamps), fs.book, name, 1,
                                    heliostat_ids=["H02"]).run()
            finally:
                lamps.close()
                if peer is not None:
                    peer.__exit__(None, None, None)

        def recorded(o, name: str, code: int) -> bool:
            line = str(o) if isinstance(o, HeliocalError) else getattr(o, "cause", None)
            status = o.exit_code if isinstance(o, HeliocalError) else getattr(o, "exit_code", None)
            rec = next((n for n in NightBook(store).nights() if n.name == name), None)
            return (line is not None and "\n" not in line and status == code and rec is not None
                    and rec.status == "aborted" and bool(rec.cause))

        with contextlib.suppress(HeliocalError):  # the imports, not counted
            night("adversarial/warm-up", faults["program-fails"]())
        for fault, section in faults.items():
            name = f"adversarial/{fault}"
            t.case(fault, lambda n=name, s=section: night(n, s() if callable(s) else s),
                   lambda o, n=name: recorded(o, n, 1))
        for lamp in ("lamp-gone", "sun"):  # no longer configured; not a lamp
            name = f"adversarial/stale-plan-{lamp}"
            rec, _ = fs.book.open_night(name, "planned")
            fs.book.record_plan([PlanItem("H02", name, Geometry(lamp, (0.0, 0.0, 30.0), (0, 0), (0, 0)),
                                          1, 0.1, 1.0, 0.5)])
            fs.book.finish_night(rec.id, "interrupted", "stopped by the operator", {})
            t.case(f"stale plan {lamp}", lambda n=name: PlannedNight(fs.field, fs.book, n, 1,
                                                                      heliostat_ids=["H02"]).run(),
                   lambda o, n=name: recorded(o, n, 2))
    store.close()
    return t.report()


def _always_lit(folder: Path) -> Path:
    """A switch program whose every switch succeeds and whose status always says lit."""
    p = folder / "always-lit"
    p.write_text("#!/bin/sh\nexit 0\n")
    p.chmod(0o755)
    return p


def categories(folder: Path) -> dict[str, dict]:
    """The three categories, their files under ``folder/lamps``."""
    root = folder / "lamps"
    programs, peers, nights = root / "programs", root / "peers", root / "nights"
    for f in (programs, peers, nights):
        f.mkdir(parents=True)
    return {"lamp_programs": lamp_programs(programs), "lamp_panel_peers": lamp_panel_peers(peers),
            "night_lamp_failures": night_lamp_failures(nights)}
