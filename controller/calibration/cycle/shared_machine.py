"""One state machine for every calibration cycle, and state timeouts without a thread per state.

A ``transitions`` machine built per cycle (states, ~55 transitions) cost 2 ms, and its
``Timeout`` state feature started a ``threading.Timer`` — a new thread — each time a state was
entered: a cycle enters about a dozen states per measurement, so a night of 30,000
measurements built 30,000 machines and started some 400,000 threads, half of the state
machine's cost. :func:`shared_machine` builds the machine of a table once per distinct set of
timeouts; each cycle is added to it as a model and removed when it ends.
:class:`SharedTimeout` keeps the ``Timeout`` feature's contract (``timeout`` wall seconds,
``on_timeout`` callbacks run on a thread of their own once the state has been held that long;
leaving the state first cancels them) over one scheduler thread for every cycle of the process
(:class:`Deadlines`); a thread is started only when a timeout actually fires.

A cycle's ``on_timeout`` is its method ``_timeout_<state>``, its trigger ``timeout`` is allowed
by its method ``_timeout_is_current``, and ``_state_changed`` / ``_on_exception`` are called
after each change and on an exception (:mod:`controller.calibration.cycle.machine`).
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable
from functools import partial
from types import MethodType

from transitions.extensions import LockedMachine
from transitions.extensions.states import Timeout, add_state_features


class Deadlines:
    """Calls due after a delay (wall seconds), on one daemon thread; each due call runs on a
    thread of its own, so a callback that blocks delays no other."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._heap: list[list] = []  # [due, seq, call, args]; call None once cancelled or fired
        self._cancelled = 0
        self._seq = itertools.count()
        self._thread: threading.Thread | None = None

    def add(self, delay_s: float, call: Callable, *args) -> list:
        """Schedule ``call(*args)`` in ``delay_s`` wall seconds; returns its handle."""
        entry = [time.monotonic() + delay_s, next(self._seq), call, args]
        with self._cv:
            heapq.heappush(self._heap, entry)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="state-timeouts", daemon=True)
                self._thread.start()
            if self._heap[0] is entry:
                self._cv.notify()
        return entry

    def cancel(self, entry: list) -> None:
        """The call of ``entry`` will not be made (nothing if it was already)."""
        with self._cv:
            if entry[2] is None:
                return
            entry[2] = None
            self._cancelled += 1
            if self._cancelled > 64 and self._cancelled > len(self._heap) // 2:
                # Long timeouts cancelled early would otherwise pile up until they are due.
                self._heap = [e for e in self._heap if e[2] is not None]
                heapq.heapify(self._heap)
                self._cancelled = 0

    def _run(self) -> None:
        with self._cv:
            while True:
                while self._heap and self._heap[0][2] is None:
                    heapq.heappop(self._heap)
                    self._cancelled -= 1
                if not self._heap:
                    self._cv.wait()
                    continue
                wait = self._heap[0][0] - time.monotonic()
                if wait > 0:
                    self._cv.wait(wait)
                    continue
                entry = heapq.heappop(self._heap)
                call, args = entry[2], entry[3]
                entry[2] = None
                threading.Thread(target=call, args=args, name="state-timeout", daemon=True).start()


DEADLINES = Deadlines()


class SharedTimeout(Timeout):
    """``transitions``' ``Timeout`` state feature over :data:`DEADLINES` (module docstring)."""

    def enter(self, event_data):
        if self.timeout > 0:
            self.runner[id(event_data.model)] = DEADLINES.add(self.timeout, self._process_timeout, event_data)
        return super(Timeout, self).enter(event_data)

    def exit(self, event_data):
        entry = self.runner.pop(id(event_data.model), None)
        if entry is not None:
            DEADLINES.cancel(entry)
        return super(Timeout, self).exit(event_data)


@add_state_features(SharedTimeout)
class SharedMachine(LockedMachine):
    """A locked machine with :class:`SharedTimeout` states whose models come and go. Its models
    call ``trigger(name)`` and read ``state``, nothing else: :meth:`add_model` binds neither a
    method per trigger nor ``may_*``/``is_*`` (some forty partials, half a millisecond a cycle),
    and a model's ``on_enter_<state>``/``on_exit_<state>`` methods are not looked for."""

    def __getattribute__(self, item):
        # LockedMachine's, without inspect and str.startswith: the machine reads its own
        # attributes some 800 times per cycle, and this was 3 % of a night's controller CPU.
        value = object.__getattribute__(self, item)
        if item[0] != "_" and type(value) is MethodType:
            return partial(object.__getattribute__(self, "_locked_method"), value)
        return value

    def add_model(self, model, initial=None):
        """Add one ``model`` in ``initial`` (default the machine's initial state), given
        ``trigger`` only (class docstring)."""
        model.trigger = partial(self._get_trigger, model)
        self.set_state(self.initial if initial is None else initial, model=model)
        self.models.append(model)
        self.model_context_map[id(model)].extend(self.machine_context)

    def remove_model(self, model):
        """Remove ``model``, cancelling the timeout of the state it ends in (a final state is never
        left). A trigger on it afterwards (an abort racing its end) finds it in a final state."""
        for state in self.states.values():
            entry = state.runner.pop(id(model), None)
            if entry is not None:
                DEADLINES.cancel(entry)
        return super().remove_model(model)


_MACHINES: dict[tuple, SharedMachine] = {}
_MACHINES_LOCK = threading.Lock()


def shared_machine(states: tuple[tuple[str, float, str], ...], transitions: tuple, timeouts: dict[str, float]
                   ) -> SharedMachine:
    """The machine of the tables ``states`` ((name, timeout s, what), the first the initial state)
    and ``transitions`` ((trigger, source(s), destination)) with ``timeouts`` overriding the
    table's (module docstring for the names its models provide), built once per distinct set."""
    key = (id(states), id(transitions), tuple(timeouts.get(s, t) for s, t, _ in states))
    with _MACHINES_LOCK:
        machine = _MACHINES.get(key)
        if machine is None:
            table = [{"name": s, "timeout": t, "on_timeout": f"_timeout_{s}"}
                     for (s, _, _), t in zip(states, key[2], strict=True)]
            machine = SharedMachine(model=None, states=table,
                                    initial=states[0][0], auto_transitions=False,
                                    after_state_change="_state_changed", on_exception="_on_exception",
                                    send_event=False)
            for trig, src, dst in transitions:
                machine.add_transition(trig, list(src) if isinstance(src, tuple) else src, dst,
                                       conditions=["_timeout_is_current"] if trig == "timeout" else None)
            _MACHINES[key] = machine
    return machine
