"""The records a calibration creates: one run of one heliostat with its measurements,
corrections, images and fitted model, and the campaign they belong to.

The orchestration layer creates them; :mod:`controller.storage.db` maps them to SQLite and
back. Conventions: positions ENU metres, directions ENU unit vectors, azimuth clockwise from
north in degrees, errors in mrad (reflected-beam angle), wall times ISO-8601 UTC strings,
plant times in seconds of the plant clock (``*_s``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from controller.devices.plant_time import utc_now
from controller.geometry.aiming import pointing_error_mrad
from controller.geometry.vectors import vector_to_azel


@dataclass
class ImageRecord:
    kind: str  # "low", "high" or "hdr"
    path: str
    sha256: str
    exposures: tuple[float, float]


@dataclass
class MeasurementRecord:
    """One beam measurement. ``source_pos_enu``: the lamp's position (m ENU; None for the
    sun). ``id``, ``run_id``, ``campaign_id`` and ``heliostat_id`` are set when read back from
    the store."""

    iteration: int
    az_steps: int
    el_steps: int
    source_dir: tuple[float, float, float]
    source_az_deg: float
    source_el_deg: float
    aim_enu: tuple[float, float, float]
    plant_time_s: float
    centroid_enu: tuple[float, float, float] | None = None
    centroid_px: tuple[float, float] | None = None
    error_mrad: float | None = None
    matched_label: str | None = None
    match_distance: float | None = None
    runner_up_label: str | None = None
    runner_up_distance: float | None = None
    measured_utc: str = field(default_factory=utc_now)
    source_pos_enu: tuple[float, float, float] | None = None
    images: list[ImageRecord] = field(default_factory=list)
    id: int | None = None
    run_id: int | None = None
    campaign_id: int | None = None
    heliostat_id: str | None = None


@dataclass
class CorrectionRecord:
    iteration: int
    kind: str  # "coarse" (library case) or "fine" (centroid offset through the Jacobian)
    daz_deg: float
    del_deg: float
    daz_steps: int
    del_steps: int


@dataclass
class ModelRecord:
    """A heliostat's fitted tracking model: ``params`` and 1-σ ``sigma`` by term key (mrad or
    mm, docs/tracking-model.md), training residual RMS (mrad), number of measurements, and
    ``detail``: ``covariance_si`` (terms × terms, SI²), ``identified`` (term names) and
    ``noise_scale`` (empty for models of older versions)."""

    params: dict[str, float]
    sigma: dict[str, float | None]
    residual_mrad: float | None
    n_measurements: int
    detail: dict = field(default_factory=dict)


@dataclass
class SearchRecord:
    """A heliostat's beam search (``calibration.search``, docs/commissioning.md): ``looks`` taken
    after the first found no spot in view, ``skipped`` pattern points refused by beam safety or
    out of reach, ``seconds`` of plant time from the first look without a spot until the spot was
    in view (or the search gave up), ``found``, ``offsets_m`` the pattern offsets (u, v; m in
    the target plane from the aim point) looked at in order, the first look's (0, 0) included;
    ``miss_m`` (u, v) where the beam of the starting pose (the nominal model's, or the fitted one's)
    landed relative to the aim point: the first centroid in view less the offset it was seen at
    (None when never seen)."""

    looks: int = 0
    skipped: int = 0
    seconds: float = 0.0
    found: bool = False
    offsets_m: list[tuple[float, float]] = field(default_factory=list)
    miss_m: tuple[float, float] | None = None


@dataclass
class RunRecord:
    """Outcome of one heliostat's calibration cycle, written atomically with its children.

    ``status``: ``calibrated`` (within tolerance), ``not_converged`` (max iterations reached),
    ``measured`` (an observation of a planned night: one measurement, no correction),
    ``no_beam`` (a frame held no beam: nothing computed from it, controller.calibration.campaign.no_beam)
    or ``failed`` (fault; ``fault_cause`` says why, ``fault_state`` where). ``id`` and
    ``finished_utc`` are set when read back from the store."""

    heliostat_id: str
    queue_index: int
    status: str
    final_state: str
    iterations: int
    start_s: float
    end_s: float
    error_before_mrad: float | None = None
    error_after_mrad: float | None = None
    matched_label: str | None = None
    fault_cause: str | None = None
    fault_state: str | None = None
    at_standby_s: float | None = None
    on_target_s: float | None = None
    off_target_s: float | None = None
    measurements: list[MeasurementRecord] = field(default_factory=list)
    corrections: list[CorrectionRecord] = field(default_factory=list)
    model: ModelRecord | None = None
    id: int | None = None
    finished_utc: str | None = None
    frames: list[ImageRecord] = field(default_factory=list)  # the look that gave no measurement
    search: SearchRecord | None = None  # the beam search, when the configuration enables one

    @property
    def target_occupancy_s(self) -> float | None:
        """Plant seconds from the approach command until the beam was parked again."""
        if self.off_target_s is None or self.on_target_s is None:
            return None
        return self.off_target_s - self.on_target_s

    @property
    def sequential_share_s(self) -> float:
        """Plant time the run would add one after another: its slew to standby plus its time
        from the approach to the end (its wait for the target does not exist then)."""
        prep = (self.at_standby_s - self.start_s) if self.at_standby_s is not None else 0.0
        start = self.on_target_s if self.on_target_s is not None else (self.at_standby_s or self.start_s)
        return max(0.0, prep) + max(0.0, self.end_s - start)


# How a campaign's last session ended: every heliostat calibrated; every heliostat recorded
# but some failed or did not converge; stopped by a fault (a beam may be left on the target, a
# device is missing); stopped by the operator (Ctrl-C, SIGTERM). ``running`` while it runs.
CAMPAIGN_STATUSES = ("finished", "partial", "aborted", "interrupted")
# A heliostat run's outcome (RunRecord.status); records are refused on reading with another.
RUN_STATUSES = ("calibrated", "not_converged", "measured", "no_beam", "failed")


@dataclass
class CampaignRecord:
    """One campaign as stored: its configuration, queue and outcome (``status`` one of
    :data:`CAMPAIGN_STATUSES` or ``running``, ``cause`` why it ended so)."""

    id: int
    name: str
    config_path: str
    config_sha256: str
    light_source: str
    target: str
    queue: list[str]
    started_utc: str
    finished_utc: str | None
    status: str
    meta: dict
    cause: str | None = None


def measurement_record(pointing, obs, match, iteration: int, steps: tuple[int, int], plant_time_s: float,
                       utc: str) -> MeasurementRecord:
    """The record of one measurement: the beam ``obs`` (:class:`Observation`) seen at motor
    ``steps`` under ``pointing``'s light source and aim point, with the library's ``match``
    (or None); its error is the reflected-beam angle from the aim point, mrad."""
    p, m = pointing, match
    saz, sel = vector_to_azel(p.source_dir)
    return MeasurementRecord(
        iteration=iteration, az_steps=steps[0], el_steps=steps[1],
        source_dir=tuple(float(c) for c in p.source_dir), source_az_deg=float(saz),
        source_el_deg=float(sel), aim_enu=tuple(float(c) for c in p.aim_point),
        plant_time_s=plant_time_s, measured_utc=utc, source_pos_enu=p.source_pos,
        centroid_enu=tuple(float(c) for c in obs.centroid_enu),
        centroid_px=(float(obs.centroid_px[0]), float(obs.centroid_px[1])),
        error_mrad=pointing_error_mrad(p.heliostat_pos, p.aim_point, obs.centroid_enu),
        matched_label=None if m is None or m.unknown else m.label,
        match_distance=None if m is None else m.distance,
        runner_up_label=None if m is None else m.runner_up,
        runner_up_distance=None if m is None else m.runner_up_distance)


NIGHT_KINDS = ("calibration", "planned")


@dataclass
class NightRecord:
    """One night as stored: its ``index`` (0 the field's calibration night, then each planned
    night), ``name`` (its passes are the campaigns named ``<name>/...``; a calibration night's
    campaign has the night's name), ``kind`` (:data:`NIGHT_KINDS`), how it ended and its
    summary (the ``campaign night --json`` keys)."""

    id: int
    index: int
    name: str
    kind: str
    started_utc: str
    finished_utc: str | None
    status: str
    cause: str | None
    summary: dict
