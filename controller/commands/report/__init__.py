"""``heliocal report {weighting,confusion,campaign,first-light}``: study and campaign reports."""

from controller.commands._groups import register_group


def register(subparsers) -> None:
    register_group(subparsers, __name__, "write reports (plots, tables) into a directory")
