"""Settings of the simulated plant (kept out of the product's plant configuration)."""

from __future__ import annotations

from dataclasses import dataclass

from controller.errors import InputError


@dataclass(frozen=True)
class SimulationSettings:
    """``clock_speedup``: plant seconds per wall second while the controller waits;
    ``seed``: hidden errors, error cases and noise; ``tracking_error_mrad``: scale of the
    hidden per-heliostat errors (each parameter ~ N(0, (scale/2)²))."""

    clock_speedup: float = 20.0
    seed: int = 0
    tracking_error_mrad: float = 3.0

    def __post_init__(self) -> None:
        if not 0 < self.clock_speedup <= 1000:
            raise InputError(f"simulation clock speedup must be in (0, 1000], got {self.clock_speedup}")
        if not 0 <= self.tracking_error_mrad <= 50:
            raise InputError("simulation tracking error must be in [0, 50] mrad, "
                             f"got {self.tracking_error_mrad}")
