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


def far_lamp_config(source: Path, folder: Path, beams_per_target: int, extra_rows: int = 0) -> Path:
    """``source`` (a plant configuration) under :data:`FAR_LAMPS`, the first the calibration
    lamp, with ``calibration.beams_per_target``, written to ``folder``/bench.yaml.
    ``extra_rows``: rows of the first row's heliostats staggered into the field (:func:`_rows`;
    each row its own serial bus, mirrors focused at their distance from the calibration target)."""
    data = yaml.safe_load(Path(source).read_text())
    data["heliostats"] += _rows(data, extra_rows)
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


def _rows(data: dict, rows: int) -> list[dict]:
    """``rows`` rows of the first row's heliostats staggered into the field: halfway between
    two of its rows first (nearest the target first), then 7.5 m before its first row and
    after its last, each row's columns a quarter spacing aside so no mirror stands straight
    behind another."""
    ys = sorted({h["position_enu_m"][1] for h in data["heliostats"]})
    y0 = ys[0]
    first = [h for h in data["heliostats"] if h["position_enu_m"][1] == y0]
    xs = sorted(h["position_enu_m"][0] for h in first)
    aside = 0.25 * (xs[1] - xs[0]) if len(xs) > 1 else 2.0
    half = 0.5 * (ys[1] - ys[0]) if len(ys) > 1 else 7.5
    places = [0.5 * (a + b) for a, b in zip(ys, ys[1:], strict=False)]
    places += [y for n in range(1, rows + 1) for y in (ys[0] - n * half, ys[-1] + n * half)]
    centre = next(t for t in data["targets"] if t["id"] == data["calibration"]["target"])["center_enu_m"]
    out = []
    for r, y in enumerate(places[:rows]):
        for i, h in enumerate(first):
            x, _, z = h["position_enu_m"]
            pos = [x + aside, y, z]
            dist = sum((a - b) ** 2 for a, b in zip(pos, centre, strict=True)) ** 0.5
            out.append({**h, "id": f"R{r + 1}{i + 1:02d}", "position_enu_m": pos,
                        "mirror": {**h["mirror"], "focal_length_m": round(dist, 1)},
                        "link": {"kind": "serial", "device": f"/tmp/heliocal-demo/row{r + 1}",
                                 "address": i + 1}})
    return out
