"""Lamps switched by the plant's own program (``lamps.driver: command``, docs/lamps.md).

The controller runs the configured argv (no shell) with two arguments appended:

* ``on CHANNEL`` / ``off CHANNEL``: exit 0 once the lamp is in that state (switched *and*
  confirmed by the plant's controller); anything else is a :class:`LampCommandError`;
* ``status CHANNEL``: exit 0 when the lamp is lit, 1 when it is dark; anything else is an error.

``camera.registration.lamp_command`` (docs/camera.md, "Registration") is the same driver with
one channel, the target's fiducial lamps, and no channel argument: ``argv + [on|off]``, and no
``status`` verb — a switch that exited 0 is its confirmation (:func:`fiducial_command_panel`).
"""

from __future__ import annotations

import errno
import os
import selectors
import signal
import subprocess
import time

from controller.devices.lamp_panel import LampError, LampPanel, LampState

LAMP_COMMAND_TIMEOUT_S = 30.0  # camera.registration.lamp_command
OUTPUT_LIMIT_BYTES = 64 * 1024  # stdout and stderr each: a switch program says a line or two
_FIDUCIALS = "fiducials"
_QUOTED_CHARS = 200  # of the program's last line, in an error


class LampCommandError(LampError):
    """The switch program failed, timed out or could not be started."""


class CommandLampPanel(LampPanel):
    """``argv`` run per request; ``key`` is the configuration key messages name.
    ``with_status=False``: the program knows no ``status`` verb and takes no channel argument
    (the registration's ``lamp_command``)."""

    def __init__(self, argv: tuple[str, ...], channels: tuple[str, ...], timeout_s: float, *,
                 key: str = "lamps.command", with_status: bool = True) -> None:
        self.argv = tuple(argv)
        self.channels = tuple(channels)
        self.timeout_s = timeout_s
        self.name = key
        self.with_status = with_status
        self._commanded: dict[str, bool] = {}

    def _what(self, channel: str) -> str:
        return f"lamp {channel}" if self.with_status else "the fiducial lamps"

    def _run(self, verb: str, channel: str, doing: str) -> tuple[int, list[str]]:
        """(exit status, the lines it printed on stderr, else stdout): :func:`run_bounded`."""
        cmd = [*self.argv, verb, channel] if self.with_status else [*self.argv, verb]
        code, out, err = run_bounded(cmd, self.timeout_s, key=self.name, doing=doing)
        return code, (err or out).strip().splitlines()

    def _failed(self, doing: str, code: int, said: list[str]) -> LampCommandError:
        how = f"exited {code}" if code >= 0 else f"was killed by signal {-code}"
        return LampCommandError(f"{self.name}: {doing} {how}" + (f": {_quoted(said[-1])}" if said else ""))

    def switch(self, channel: str, on: bool) -> None:
        state = "on" if on else "off"
        doing = f"switching {self._what(self.check_channel(channel))} {state}"
        code, said = self._run(state, channel, doing)
        if code != 0:
            self._commanded.pop(channel, None)  # unknown now
            raise self._failed(doing, code, said)
        self._commanded[channel] = bool(on)

    def confirmed(self, channel: str) -> bool:
        self.check_channel(channel)
        if not self.with_status:
            return self._commanded.get(channel, False)  # exit 0 of the switch confirmed it
        doing = f"asking the status of {self._what(channel)}"
        code, said = self._run("status", channel, doing)
        if code not in (0, 1):
            raise self._failed(doing, code, said)
        return code == 0

    def states(self) -> list[LampState]:
        return [LampState(c, self._commanded.get(c), self.confirmed(c)) for c in self.channels]

    def close(self) -> None:
        """Nothing is held open between runs."""


def fiducial_command_panel(argv: tuple[str, ...]) -> tuple[CommandLampPanel, str]:
    """``camera.registration.lamp_command`` as a panel, and its one channel's name."""
    return (CommandLampPanel(argv, (_FIDUCIALS,), LAMP_COMMAND_TIMEOUT_S,
                             key="camera.registration.lamp_command", with_status=False), _FIDUCIALS)


def run_bounded(cmd: list[str], timeout_s: float, *, key: str, doing: str,
                limit: int = OUTPUT_LIMIT_BYTES) -> tuple[int, str, str]:
    """Run ``cmd`` (no shell, stdin empty) in a process group of its own; (exit status,
    stdout, stderr), decoded as UTF-8 with undecodable bytes replaced.

    Bounded on every path (docs/lamps.md, "The command driver"): more than ``limit`` bytes on
    stdout or stderr, or no exit within ``timeout_s``, is a :class:`LampCommandError` naming
    the configuration ``key`` and what it was ``doing``. When the program exits, or fails, or
    the caller is interrupted, its whole process group is killed: a child it left behind
    holding its output does not keep us waiting, nor does it stay running. A program the
    system cannot start (missing, not executable, no ``#!`` line, another machine's binary)
    is named in one line."""
    try:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, start_new_session=True)
    except (OSError, ValueError) as exc:  # ValueError: a NUL in an argument
        raise LampCommandError(f"{key}: {_cannot_start(cmd[0], exc)}") from None
    deadline = time.monotonic() + timeout_s
    out = {proc.stdout: bytearray(), proc.stderr: bytearray()}
    open_pipes = set(out)  # not at their end yet
    pidfd = os.pidfd_open(proc.pid)
    try:
        with selectors.DefaultSelector() as sel:
            for pipe in out:
                sel.register(pipe, selectors.EVENT_READ)
            sel.register(pidfd, selectors.EVENT_READ)
            exited = False
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise LampCommandError(f"{key}: {doing} did not finish within {timeout_s:g} s")
                # Once it exited, only what is already in the pipes is read: a child holding
                # them open is killed with the group below.
                ready = sel.select(0 if exited else left)
                if exited and not ready:
                    break
                for ready_key, _ in ready:
                    if ready_key.fileobj == pidfd:
                        exited = True
                        sel.unregister(pidfd)
                        continue
                    chunk = os.read(ready_key.fd, 65536)
                    if not chunk:
                        sel.unregister(ready_key.fileobj)
                        open_pipes.discard(ready_key.fileobj)
                        continue
                    buf = out[ready_key.fileobj]
                    buf += chunk
                    if len(buf) > limit:
                        stream = "stdout" if ready_key.fileobj is proc.stdout else "stderr"
                        raise LampCommandError(f"{key}: {doing}: the program printed more than {limit} bytes "
                                               f"on {stream}")
                if exited and not sel.get_map():
                    break
    finally:
        # The leader is not reaped yet (a zombie keeps the group's id ours): the whole group
        # goes, whatever ended the loop.
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        # A child that left the group (setsid) but still holds the output goes too.
        for pid in _holders({os.fstat(p.fileno()).st_ino for p in open_pipes}):
            try:
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        os.close(pidfd)
        proc.stdout.close()
        proc.stderr.close()
        proc.wait()
    return (proc.returncode, out[proc.stdout].decode("utf-8", "replace"),
            out[proc.stderr].decode("utf-8", "replace"))


def _holders(inodes: set[int]) -> list[int]:
    """The processes other than this one that hold one of the pipes ``inodes`` open (Linux
    ``/proc/PID/fd``; those of other users cannot be read, nor killed)."""
    if not inodes:
        return []
    links, me, found = {f"pipe:[{i}]" for i in inodes}, os.getpid(), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                if os.readlink(f"/proc/{pid}/fd/{fd}") in links and int(pid) != me:
                    found.append(int(pid))
                    break
            except OSError:
                continue
    return found


def _cannot_start(program: str, exc: OSError | ValueError) -> str:
    """Why the system cannot run ``program`` (``exc`` from starting it), in words."""
    if isinstance(exc, FileNotFoundError):
        return f"{program!r} not found (or the interpreter its #! line names)"
    if getattr(exc, "errno", None) == errno.ENOEXEC:
        return (f"{program!r} cannot be executed: not a program for this system "
                "(a script without a #! line, a binary of another format)")
    if isinstance(exc, PermissionError):
        return f"{program!r} is not executable"
    return f"{program!r} cannot be started: {getattr(exc, 'strerror', None) or exc}"


def _quoted(line: str) -> str:
    """The program's ``line`` as an error quotes it: printable, at most :data:`_QUOTED_CHARS`."""
    line = "".join(c if c.isprintable() else "?" for c in line)
    return line if len(line) <= _QUOTED_CHARS else line[:_QUOTED_CHARS - 1] + "…"
