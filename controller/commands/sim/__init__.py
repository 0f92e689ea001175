"""``heliocal sim {plant,firmware,lamp-panel,errorset}``: the simulated plant, whole on real
transports or in pieces."""

from controller.commands._groups import register_group


def register(subparsers) -> None:
    register_group(subparsers, __name__, "run the simulated plant on real transports, whole or in pieces")
