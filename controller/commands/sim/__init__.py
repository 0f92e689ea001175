"""``heliocal sim {firmware,errorset}``: the embedded simulated plant's pieces."""

from controller.commands._groups import register_group


def register(subparsers) -> None:
    register_group(subparsers, __name__, "run pieces of the simulated plant")
