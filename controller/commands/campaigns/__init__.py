"""Campaign commands: ``heliocal campaign`` (run, night, list, flags, ...) and ``heliocal demo``,
with their helpers. A shelf: each public module is a top-level command (see
:mod:`controller.commands`)."""
