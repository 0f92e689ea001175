"""``heliocal report {weighting,confusion,campaign}``: study and campaign reports."""

from controller.commands._groups import register_group


def register(subparsers) -> None:
    register_group(subparsers, "report", "write reports (plots, tables) into a directory")
