"""Commands on images and the error library: ``crf``, ``flux``, ``library``, ``match``. A shelf:
each public module is a top-level command (see :mod:`controller.commands`)."""
