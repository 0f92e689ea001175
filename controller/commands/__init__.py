"""CLI sub-commands, one module each; see :mod:`controller.cli` for the convention."""
