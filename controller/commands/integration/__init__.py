"""Plant-integration commands: ``alarms``, ``audit``, ``users``, ``opcua``, and their database and
operator helpers. A shelf: each public module is a top-level command (see
:mod:`controller.commands`)."""
