"""CLI sub-commands, by subject; see :mod:`controller.cli` for the convention.

* A public module here with ``register(subparsers)`` is one top-level command (``export``,
  ``merge``, ``reprocess``, ``console``, ``commission``).
* A *shelf* — a package without ``register`` (``campaigns/``, ``devices/``, ``images/``,
  ``integration/``) — holds top-level commands of one subject: each public module in it is a
  command as if it stood here (``heliocal drive``, not ``heliocal devices drive``).
* A package with ``register`` is a command group (``model``, ``report``, ``sim``, ``import``):
  ``heliocal GROUP SUBCOMMAND`` (:mod:`controller.commands._groups`).
* Modules starting with ``_`` are the commands' helpers.
* :data:`ENTRY_POINTS` are public modules that are not commands: the pieces benchmarks, tests,
  the console and OPC UA call — the option helpers (``common``), the real field
  (``field``), the simulated one (``simulated``, the only module outside ``sim/`` that imports
  :mod:`simplant`) and the planned night on a cheap simulated field (``cheap_night``).

Commands may import every layer below (orchestration, domain, drivers, wire, ``controller.io``)
and the other interfaces (storage, reports, console); nothing below imports a command.
"""

ENTRY_POINTS = frozenset({"cheap_night", "common", "field", "simulated"})
