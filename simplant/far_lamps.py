"""The demo plant lit by lamps far from its field, where several beams fit on one target.

A lamp a few tens of metres from the field is imaged far behind the target by a mirror
focused at ~50 m: its spot is nearly as wide as the mirror (controller/geometry/spot.py,
Eq. 1) and one beam fills a target. Lamps about 300 m away make spots of about a metre.
Used by ``benchmarks/bench_beams.py`` and the several-beams tests.
"""

from __future__ import annotations

from pathlib import Path

import yaml

# Twice as far as the demo's far lamps in the same directions from the field, and one south of
# the tower like a low sun: every heliostat reaches all three.
FAR_LAMPS = (("lamp-far-w", (-300.0, -15.0, 78.0)), ("lamp-far-e", (300.0, -15.0, 78.0)),
             ("lamp-far-s", (0.0, -250.0, 120.0)))


def far_lamp_config(source: Path, folder: Path, beams_per_target: int) -> Path:
    """``source`` (a plant configuration) under :data:`FAR_LAMPS`, the first the calibration
    lamp, with ``calibration.beams_per_target``, written to ``folder``/bench.yaml."""
    data = yaml.safe_load(Path(source).read_text())
    data["light_sources"] += [{"kind": "lamp", "id": i, "position_enu_m": list(p), "diameter_m": 0.3}
                              for i, p in FAR_LAMPS]
    cal = data["calibration"]
    cal["light_source"] = FAR_LAMPS[0][0]
    cal["lamps"] = [i for i, _ in FAR_LAMPS]
    cal["beams_per_target"] = beams_per_target
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "bench.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
