"""Settings of the simulated plant (kept out of the product's plant configuration)."""

from __future__ import annotations

from dataclasses import dataclass

from controller.errors import InputError

# The largest hidden-error scale: a new field's mirror normals miss by as much as 200 mrad.
MAX_TRACKING_ERROR_MRAD = 200.0


@dataclass(frozen=True)
class SimulationSettings:
    """``clock_speedup``: plant seconds per wall second while the controller waits;
    ``seed``: hidden errors, error cases and noise; ``tracking_error_mrad``: scale of the
    hidden per-heliostat errors (3: as ``hidden_errors`` gives them); ``hidden_errors``: how
    the field is built, ``assumed`` (the simulator's assumptions), ``paint-field`` (what 16
    real Jülich heliostats show) or ``first-light`` (a new field, as those heliostats were before
    their first calibration; :data:`simplant.truth.HIDDEN_ERRORS`)."""

    clock_speedup: float = 20.0
    seed: int = 0
    tracking_error_mrad: float = 3.0
    hidden_errors: str = "assumed"

    def __post_init__(self) -> None:
        if not 0 < self.clock_speedup <= 1000:
            raise InputError(f"simulation clock speedup must be in (0, 1000], got {self.clock_speedup}")
        from simplant.truth import HIDDEN_ERRORS

        if self.hidden_errors not in HIDDEN_ERRORS:
            raise InputError(f"hidden errors must be one of {', '.join(HIDDEN_ERRORS)}, "
                             f"got {self.hidden_errors!r}")
        if not 0 <= self.tracking_error_mrad <= MAX_TRACKING_ERROR_MRAD:
            raise InputError(f"simulation tracking error must be in [0, {MAX_TRACKING_ERROR_MRAD:g}] mrad, "
                             f"got {self.tracking_error_mrad}")
