"""Commands that act on one device of the plant or compute its geometry: ``drive``, ``aim``,
``beam``, ``capture``, ``lamps``, ``sun``, ``glare``. A shelf: each public module is a top-level
command (see :mod:`controller.commands`)."""
