"""What the pages read: the plant and heliostats as JSON, the beam image with its overlay, and
the reports (morning report of a campaign, confusion reports found under ``--reports``).

Conventions: ENU metres (x east, y north), motor steps, errors and σ in mrad.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.console.backend import Console
from controller.errors import InputError
from controller.geometry.model.tracking import TERMS
from controller.io.json_files import load_json
from controller.storage.trends import heliostat_trends

MIN_IMAGE_WIDTH = 640  # small camera images are scaled up (nearest) so the marks stay readable


def plant_json(c: Console) -> dict:
    cfg = c.cfg
    t = cfg.target()
    return {"site": cfg.site.name, "plant": c.hooks.label,
            "target": {"id": t.id, "center_enu_m": list(t.center_enu_m), "width_m": t.width_m,
                       "height_m": t.height_m},
            "light_source": cfg.light_source().id,
            "heliostats": [{"id": hid, "position_enu_m": list(cfg.heliostat(hid).position_enu_m),
                            "link": cfg.heliostat(hid).link.kind} for hid in c.ids],
            "library": c.library_path, "tolerance_mrad": cfg.calibration.tolerance_mrad}


def model_json(model) -> dict | None:
    """The latest fitted model: parameters and σ (each key names its unit, ``_mrad`` or
    ``_mm``), the largest σ of the angle terms (``sigma_max_mrad``) and of the length terms
    (``sigma_max_mm``) — never one figure over both units —, the residual. ``sigma_max`` (the
    largest σ whatever its unit) is kept for scripts that read it."""
    if model is None:
        return None

    def largest(unit: str) -> float | None:
        sig = [model.sigma.get(t.key) for t in TERMS if t.unit == unit]
        return max((v for v in sig if v is not None), default=None)

    sig = [v for v in model.sigma.values() if v is not None]
    return {"params": model.params, "sigma": model.sigma, "sigma_max": max(sig) if sig else None,
            "sigma_max_mrad": largest("mrad"), "sigma_max_mm": largest("mm"),
            "residual_mrad": model.residual_mrad, "n_measurements": model.n_measurements}


def heliostat_summary(c: Console, hid: str) -> dict:
    return heliostat_summaries(c, [hid])[0]


def heliostat_summaries(c: Console, ids: list[str]) -> list[dict]:
    """The field page's row of each of ``ids``: a few queries for all of them (the latest
    models, each heliostat's last measured error), not a few per heliostat — a field of
    10,000 is one page."""
    camp = c.campaign.snapshot() if c.campaign is not None else None
    states = {q["heliostat"]: q["state"] for q in camp["queue"]} if camp else {}
    models = c.store.latest_models(ids)
    last = last_errors(c.store)
    holder = c.holder()
    return [{"id": hid, "status": c.status[hid], "link": c.health[hid].to_json(),
             "model": model_json(models.get(hid)), "last_error_mrad": last.get(hid),
             "campaign_state": states.get(hid), "holds_target": holder == hid} for hid in ids]


def last_errors(store) -> dict[str, float]:
    """Each heliostat's last measured pointing error (mrad), one query."""
    rows = store.query("SELECT r.heliostat_id AS hid, m.error_mrad AS e FROM measurements m "
                       "JOIN heliostat_runs r ON m.run_id=r.id WHERE m.id IN (SELECT MAX(m2.id) FROM "
                       "measurements m2 JOIN heliostat_runs r2 ON m2.run_id=r2.id "
                       "WHERE m2.error_mrad IS NOT NULL GROUP BY r2.heliostat_id)")
    return {r["hid"]: r["e"] for r in rows}


def heliostat_detail(c: Console, hid: str) -> dict:
    out = heliostat_summary(c, hid)
    h = c.cfg.heliostat(hid)
    sl = h.axes
    out["limits"] = {"az": [sl.azimuth.soft_limits.min_steps, sl.azimuth.soft_limits.max_steps],
                     "el": [sl.elevation.soft_limits.min_steps, sl.elevation.soft_limits.max_steps]}
    out["position_enu_m"] = list(h.position_enu_m)
    out["link_kind"] = h.link.kind
    out["measurements"] = [
        {"id": m.id, "campaign_id": m.campaign_id, "iteration": m.iteration, "az_steps": m.az_steps,
         "el_steps": m.el_steps, "error_mrad": m.error_mrad, "matched": m.matched_label,
         "utc": m.measured_utc} for m in c.store.measurements(heliostat_id=hid)][-50:]
    out["nights"] = heliostat_trends(c.store, [hid])[hid]
    out["log"] = c.logs[hid][-30:]
    s = c.sessions.get(hid)
    cap = s.last if s is not None else None
    out["capture"] = None if cap is None else cap.to_json(s.pointing.aim_point, s.pointing.heliostat_pos)
    return out


# -- the beam image -------------------------------------------------------------------------------
@dataclass
class BeamImage:
    """What the beam image shows: the HDR frame in the view of ``target`` (an id of the
    configuration), the beam centroid (px) when one was found, the aim point that
    measurement aimed at (ENU m) and where the frame came from."""

    hdr: np.ndarray
    centroid_px: tuple[float, float] | None
    aim_enu: tuple[float, float, float]
    target: str
    source: str


def latest_image(c: Console, hid: str) -> BeamImage | None:
    """The last capture of the console's session, else the heliostat's last recorded
    measurement with a stored pair (merged in the view of its campaign's target); None if none."""
    s = c.sessions.get(hid)
    if s is not None and s.last is not None:
        o = s.last.observation
        return BeamImage(s.last.hdr, None if o is None else o.centroid_px,
                         tuple(float(v) for v in s.pointing.aim_point), c.cfg.target().id, "console capture")
    for m in reversed(c.store.measurements(heliostat_id=hid)):
        imgs = {im.kind: im for im in c.store.images(m.id)}
        if "low" in imgs and "high" in imgs and all(Path(im.path).is_file() for im in imgs.values()):
            from controller.calibration.cycle.beam_chain import BeamChain
            from controller.devices.camera import FramePair
            from controller.io.images import read_image

            frame = FramePair(read_image(imgs["low"].path), read_image(imgs["high"].path),
                              imgs["low"].exposures, 0.0)
            target = _target_of(c, c.store.campaign(m.campaign_id).target)
            hdr = BeamChain(c.cfg.for_target(target)).merge(frame)
            where = f"measurement {m.id} (campaign {m.campaign_id})"
            return BeamImage(hdr, m.centroid_px, m.aim_enu, target, where)
    return None


def _target_of(c: Console, tid: str) -> str:
    """``tid`` when the configuration has that target, else its calibration target."""
    return tid if any(t.id == tid for t in c.cfg.targets) else c.cfg.target().id


def overlay_png(c: Console, hid: str) -> bytes:
    """The last beam image (grey, scaled to its 99.9th percentile) with the target outline
    (green), that measurement's aim point (cyan ring and cross; a planned night aims off the
    target centre) and the beam centroid (red cross), as PNG bytes. Raises InputError when the
    heliostat has no image yet."""
    import cv2

    from controller.calibration.cycle.beam_chain import BeamChain

    got = latest_image(c, hid)
    if got is None:
        raise InputError(f"{hid}: no beam image yet (capture one, or run a campaign)")
    data = np.nan_to_num(np.asarray(got.hdr, float))
    top = float(np.percentile(data, 99.9)) or 1.0
    grey = np.clip(data / top * 255.0, 0, 255).astype(np.uint8)
    rows, cols = grey.shape
    k = max(1, int(np.ceil(MIN_IMAGE_WIDTH / cols)))
    img = cv2.cvtColor(cv2.resize(grey, (cols * k, rows * k), interpolation=cv2.INTER_NEAREST),
                       cv2.COLOR_GRAY2BGR)
    frame = BeamChain(c.cfg.for_target(got.target)).frame
    t = c.cfg.target(got.target)
    pitch = frame.width_m / cols  # m per camera pixel

    def px(u_m: float, v_m: float) -> tuple[int, int]:
        """Image point (scaled) of the in-plane offset (u, v) m from the target centre."""
        return (int(round(((u_m + frame.width_m / 2) / pitch) * k)),
                int(round(((v_m + frame.height_m / 2) / pitch) * k)))

    size = img.shape[1] / 1024  # marks scale with the drawn image
    thick = max(2, round(2 * size))
    cv2.rectangle(img, px(-t.width_m / 2, -t.height_m / 2), px(t.width_m / 2, t.height_m / 2), (0, 200, 0),
                  thick)
    lines = [f"{hid}: {got.source}"]
    if got.centroid_px is not None:
        x, y = got.centroid_px
        cx, cy = (int(round((x + 0.5) * k)), int(round((y + 0.5) * k)))
        cv2.drawMarker(img, (cx, cy), (0, 0, 255), cv2.MARKER_TILTED_CROSS, round(40 * size), thick + 1)
        lines.append(f"centroid x {x:.1f} y {y:.1f} px")
    else:
        lines.append("no beam found")
    # The aim point on top: a ring that stays visible on a bright spot (dark edge, cyan ring).
    d = np.asarray(got.aim_enu, float) - frame.center
    u, v = float(d @ frame.u), float(d @ frame.v)
    ax, ay = px(u, v)
    r = round(26 * size)
    cv2.circle(img, (ax, ay), r, (0, 0, 0), thick + 2)
    cv2.circle(img, (ax, ay), r, (255, 255, 0), thick)
    cv2.drawMarker(img, (ax, ay), (255, 255, 0), cv2.MARKER_CROSS, round(16 * size), thick)
    # In the image's own directions: u runs to the right, v down (TargetFrame).
    lines[-1] += (f"; aim {abs(u):.2f} m {'right' if u >= 0 else 'left'}, {abs(v):.2f} m "
                  f"{'down' if v >= 0 else 'up'} of the centre")
    _caption(img, lines, size)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise InputError(f"{hid}: could not encode the image")
    return buf.tobytes()


def _caption(img: np.ndarray, lines: list[str], size: float) -> None:
    """``lines`` in white on black at the top left, each shrunk to fit the image's width."""
    import cv2

    font, weight = cv2.FONT_HERSHEY_SIMPLEX, max(1, round(2 * size))
    y = 8
    for text in lines:
        scale = 0.95 * size
        (tw, th), _ = cv2.getTextSize(text, font, scale, weight)
        if tw + 16 > img.shape[1]:
            scale *= (img.shape[1] - 16) / tw
            (tw, th), _ = cv2.getTextSize(text, font, scale, weight)
        cv2.rectangle(img, (0, y - 8), (tw + 16, y + th + 8), (0, 0, 0), -1)
        cv2.putText(img, text, (8, y + th), font, scale, (255, 255, 255), weight, cv2.LINE_AA)
        y += th + 12


# -- reports --------------------------------------------------------------------------------------
def campaigns_json(c: Console) -> list[dict]:
    """Every campaign with what it was for: a night's pass counts its heliostats measured, a
    calibration campaign those calibrated (``done`` of ``heliostats``, ``what``)."""
    from controller.storage.nights import NightBook

    passes = NightBook(c.store).passes()
    out = []
    for camp in c.store.campaigns():
        runs = c.store.runs(camp.id)
        what = "measured" if camp.id in passes else "calibrated"
        out.append({"id": camp.id, "name": camp.name, "status": camp.status, "cause": camp.cause,
                    "started_utc": camp.started_utc, "heliostats": len(camp.queue), "recorded": len(runs),
                    "calibrated": sum(r.status == "calibrated" for r in runs),
                    "measured": sum(r.status == "measured" for r in runs), "what": what,
                    "done": sum(r.status == what for r in runs)})
    return out


def morning_report(c: Console, campaign_id: int) -> Path:
    """The morning report of a campaign (``heliocal report campaign``), written into the
    console's work folder once per state of the campaign (status, number of recorded runs)."""
    from controller.reports.campaign import write_report

    camp = c.store.campaign(campaign_id)
    out = c.work_dir / "reports" / f"c{camp.id}-{camp.status}-{len(c.store.runs(camp.id))}"
    if not (out / "report.html").is_file():
        write_report(c.store, out, camp.id)
    return out


def nights_json(c: Console) -> list[dict]:
    """The nights of the database, oldest first: index, name, kind, how it ended, geometries
    measured of those planned (a planned night), the daytime RMS its models predicted and, on a
    simulated plant, the true one (mrad)."""
    from controller.storage.nights import NightBook

    out = []
    for n in NightBook(c.store).nights():
        s = n.summary
        out.append({"index": n.index, "name": n.name, "kind": n.kind, "status": n.status, "cause": n.cause,
                    "started_utc": n.started_utc, "finished_utc": n.finished_utc,
                    "planned": s.get("planned"), "measured": s.get("measured"),
                    "daytime_error_predicted_mrad": s.get("daytime_error_predicted_mrad"),
                    "daytime_error_true_mrad": s.get("truth", {}).get("daytime_error_mrad")})
    return out


def night_report(c: Console, index: int) -> Path:
    """The morning report of night ``index`` as ``heliocal report campaign --night INDEX``
    writes it (a planned night's report, or the calibration night's campaign report), into the
    console's work folder once per state of the database (the night's status, the measurements
    recorded: a later night's refits change what an earlier night's report says of the models)."""
    from controller.reports.campaign import write_report
    from controller.reports.night import write_night_report
    from controller.storage.nights import NightBook

    night = next((n for n in NightBook(c.store).nights() if n.index == index), None)
    if night is None:
        raise InputError(f"{c.store.path}: no night {index}")
    count = c.store.query("SELECT COUNT(*) AS n FROM measurements")[0]["n"]
    out = c.work_dir / "reports" / f"n{index}-{night.status}-{count}"
    if not (out / "report.html").is_file():
        if night.kind == "planned":
            write_night_report(c.store, out, night)
        else:
            write_report(c.store, out, c.store.find_campaign(night.name).id)
    return out


def confusion_reports(c: Console) -> list[dict]:
    """Confusion reports (``heliocal report confusion``) under the ``--reports`` folder."""
    if not c.reports_dir:
        return []
    base = Path(c.reports_dir)
    out = []
    for rep in sorted(base.glob("**/report.json")):
        try:
            data = load_json(rep, "confusion report")
        except InputError:
            continue  # not a readable report: the page lists the others
        if not isinstance(data, dict) or "matrix" not in data or "labels" not in data:
            continue
        rel = rep.parent.relative_to(base).as_posix()
        out.append({"name": rel or ".", "labels": data["labels"], "matrix": data["matrix"],
                    "unknown": data.get("unknown"), "recognition_rate": data.get("recognition_rate"),
                    "features": data.get("features"),
                    "png": f"/reports/files/{rel}/confusion.png" if (rep.parent / "confusion.png").is_file()
                    else None})
    return out


def report_file(base: Path, rel: str) -> Path:
    """``rel`` inside ``base``, refusing anything that leaves it."""
    p = (base / rel).resolve()
    if not p.is_relative_to(base.resolve()) or not p.is_file():
        raise InputError(f"no such report file: {rel}")
    return p
