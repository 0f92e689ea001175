"""``heliocal model {fit,predict,refit,validate}``: the tracking model on PAINT/ARTIST records, and
every heliostat of a database refitted."""

from controller.commands._groups import register_group


def register(subparsers) -> None:
    register_group(subparsers, __name__, "fit, apply and cross-validate a heliostat's tracking model "
                                         "on PAINT/ARTIST calibration records; refit a database's models")
