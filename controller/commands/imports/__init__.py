"""``heliocal import {paint}``: another system's calibration records into the field's store (the
package is ``imports``: ``import`` is a Python keyword)."""

from controller.commands._groups import register_group


def register(subparsers) -> None:
    register_group(subparsers, __name__, "import calibration records of another system into a database",
                   name="import")
