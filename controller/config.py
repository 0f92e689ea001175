"""Plant configuration: YAML files validated into typed, frozen pydantic models.

Conventions (see docs/configuration.md):
- positions are local ENU metres (east, north, up) about the plant origin;
- azimuth is clockwise from north, angles in degrees at this edge, except the actuator
  parameters, which keep the names *and units* of the PAINT/ARTIST heliostat records
  (``increment`` in steps/m, lengths in m, ``initial_angle`` in rad);
- soft limits are in motor steps and must lie inside the hard range
  ``[min_increment, max_increment]``.

:func:`load_config` is the only entry point. Every failure (unreadable file, bad YAML,
missing or unknown key, wrong type, value out of range, broken cross-reference) raises one
:class:`controller.errors.ConfigError` whose message names the file, the key path and the
rule broken.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from controller.alarm_config import AlarmLimits
from controller.axis_config import Axes, AxisConfig, SoftLimits  # noqa: F401 - the axes section
from controller.camera_config import Camera, Gige, Sensor  # noqa: F401 - the camera section
from controller.config_rules import Direction, Position, PriorSigma, Section
from controller.errors import ConfigError, InputError
from controller.field_file import config_sha256, load_field  # noqa: F401 - config_sha256 re-exported
from controller.heliostat_config import (  # noqa: F401 - the heliostats section
    FieldFile,
    Heliostat,
    Kinematics,
    Mirror,
)
from controller.io.config_keys import did_you_mean, key_path
from controller.io.yaml_files import MAX_BYTES, parse_yaml, read_text
from controller.lamp_config import CommandLamps, Lamps, ModbusRtuLamps, ModbusTcpLamps, check_channels  # noqa: F401
from controller.link_config import (  # noqa: F401 - the links section
    Bus,
    Link,
    ModbusRtuBus,
    ModbusRtuLink,
    ModbusTcpBus,
    ModbusTcpLink,
    NoLink,
    SerialBus,
    SerialLink,
)
from controller.search_config import BeamSearch

Vec3 = tuple[float, float, float]
_Model = Section  # every section: unknown keys refused, only finite numbers (controller.config_rules)


def _unit(v: Vec3) -> Vec3:
    n = math.sqrt(sum(c * c for c in v))
    if not 0.999 <= n <= 1.001:
        raise ValueError(f"must be a unit vector (its norm is {n:.6g})")
    return v


class Site(_Model):
    name: str = "plant"
    latitude_deg: float = Field(ge=-90, le=90)
    longitude_deg: float = Field(ge=-180, le=180)
    elevation_m: float = Field(ge=-500, le=9000)
    pressure_mbar: float = Field(gt=0, le=1200)
    temperature_c: float = Field(ge=-90, le=70)
    delta_t_s: float | None = Field(default=None, ge=-100, le=300,
                                    description="TT-UT1 in s; None: estimated")


class Target(_Model):
    id: str
    center_enu_m: Position
    normal: Direction
    width_m: float = Field(gt=0, le=100)
    height_m: float = Field(gt=0, le=100)
    camera: Camera | None = Field(default=None, description="this target's camera (schema of the "
                                  "top-level camera); None: the top-level camera")

    _check_normal = field_validator("normal")(classmethod(lambda cls, v: _unit(v)))


class PersonZone(_Model):
    """A box where people may be (a stair landing, a road, the control room roof): axis-aligned
    in ENU metres, grown by ``margin_m`` on every side (the beam's own radius and the pointing
    error). No reflected beam may enter it — at a pose, on a slew or on the approach."""

    id: str
    min_enu_m: Position
    max_enu_m: Position
    margin_m: float = Field(default=2.0, ge=0, le=50)

    @model_validator(mode="after")
    def _ordered(self) -> PersonZone:
        for axis, lo, hi in zip("ENU", self.min_enu_m, self.max_enu_m, strict=True):
            if not lo < hi:
                raise ValueError(f"min_enu_m must lie below max_enu_m on every axis ({axis}: {lo} >= {hi})")
        return self


class SunSource(_Model):
    kind: Literal["sun"]
    id: str = "sun"
    angular_diameter_mrad: float = Field(default=9.3, gt=0, le=50)


class LampSource(_Model):
    kind: Literal["lamp"]
    id: str
    position_enu_m: Position
    diameter_m: float = Field(gt=0, le=10)


LightSource = Annotated[SunSource | LampSource, Field(discriminator="kind")]


class ModelSettings(_Model):
    """The tracking-model fit (docs/tracking-model.md)."""

    noise_mrad: float = Field(default=0.3, gt=0, le=50,
                              description="1-σ noise of one measured mirror normal, mrad")
    prior_sigma: dict[str, PriorSigma] = Field(
        default_factory=dict,
        description="prior 1-σ of tracking-model terms, by key (e.g. base_yaw_mrad, az_stroke0_mm); "
                    "terms not listed keep the documented defaults")
    age_halflife_days: float = Field(default=30.0, gt=0, le=3650,
                                     description="a measurement this many days older than the newest "
                                                 "weighs half in the fit (drift)")
    field_prior: str | None = Field(
        default=None, min_length=1, max_length=4096,
        description="PRIOR.json of 'heliocal model prior': the field's prior of the terms (relative to "
                    "this file's folder); none: the documented one")

    @field_validator("prior_sigma")
    @classmethod
    def _term_keys(cls, v: dict[str, float]) -> dict[str, float]:
        for key in v:
            if not (key.endswith("_mrad") or key.endswith("_mm")):
                raise ValueError(f"{key}: a term key ends in _mrad or _mm")
        return v


class AimGrid(_Model):
    """Aim points on a grid over the calibration target (planned nights, docs/campaigns.md)."""

    rows: int = Field(default=1, ge=1, le=9, description="aim points down the target")
    cols: int = Field(default=1, ge=1, le=9, description="aim points across the target")
    margin_m: float = Field(default=1.0, ge=0, le=50,
                            description="distance kept from the target's edges, m")


class Planner(_Model):
    """The nightly planner (docs/campaigns.md, "Planned nights")."""

    geometries_per_night: int = Field(default=3, ge=1, le=50,
                                      description="measurements planned per heliostat and night")
    check_geometries: int = Field(default=1, ge=0, le=50,
                                  description="measurements for a heliostat whose predicted daytime "
                                              "error is already below tolerance")
    sun_positions: int = Field(default=48, ge=4, le=2000,
                               description="sun positions of the yearly path the planner scores against")
    view_margin_m: float = Field(default=0.2, ge=0, le=50,
                                 description="distance the 3σ spot of a planned geometry keeps inside the "
                                             "camera's view, m")


class Calibration(_Model):
    light_source: str = Field(description="id of the light source used for calibration")
    target: str = Field(description="id of the calibration target (the default, first one)")
    targets: tuple[str, ...] = Field(default=(), description="ids of the targets calibrated in parallel "
                                     "(default: target only)")
    threshold: float = Field(default=0.5, gt=0, lt=1, description="beam segmentation fraction")
    centroid_threshold: float = Field(default=0.05, gt=0, lt=1,
                                      description="fraction of the peak above which pixels weigh in "
                                                  "the pointing centroid (all lobes)")
    settle_s: float = Field(default=0.5, ge=0, le=60, description="settling time after a move, s")
    pipeline_depth: int = Field(default=6, ge=1, le=64,
                                description="heliostats in their cycle at once (slewing to standby)")
    beams_per_target: int = Field(default=1, ge=1, le=8,
                                  description="heliostats measured in one capture on a target, each at "
                                              "its own slot (lamps at night only, docs/campaigns.md)")
    python_one_core: bool = Field(default=True, description="while a campaign measures, every Python "
                                  "thread of the controller on one core (docs/campaigns.md)")
    identity_settle_s: float = Field(default=0.1, ge=0, le=60,
                                     description="settling time after the identity step of a shared capture "
                                                 "(beams_per_target > 1), s; at most settle_s")
    tolerance_mrad: float = Field(default=0.5, gt=0, le=50)
    max_iterations: int = Field(default=4, ge=1, le=50)
    standby_offset_m: float = Field(default=15.0, gt=0, le=200,
                                    description="standby aim point distance beside the target")
    library: str | None = Field(default=None, description="error library YAML; None: built")
    coarse_correction: float | None = Field(default=None, ge=0, le=1, description="min. confidence of "
                                            "a clipped spot's centre estimate to move on; null: centroid")
    model: ModelSettings = Field(default_factory=ModelSettings)
    search: BeamSearch = Field(default_factory=BeamSearch, description="the beam search (first light)")
    lamps: tuple[str, ...] = Field(default=(), description="ids of the lamps planned nights may light "
                                   "(default: light_source only)")
    aim_grid: AimGrid = Field(default_factory=AimGrid)
    planner: Planner = Field(default_factory=Planner)

    def planned_lamps(self) -> tuple[str, ...]:
        return self.lamps or (self.light_source,)

    def parallel_targets(self) -> tuple[str, ...]:
        return self.targets or (self.target,)


class PlantConfig(_Model):
    site: Site
    targets: tuple[Target, ...] = Field(min_length=1)
    light_sources: tuple[LightSource, ...] = Field(min_length=1)
    heliostats: tuple[Heliostat, ...] = Field(min_length=1)
    field: FieldFile | None = Field(default=None, description="the heliostats in a file of their own "
                                    "(docs/configuration.md); None: heliostats inline")
    camera: Camera
    calibration: Calibration
    person_zones: tuple[PersonZone, ...] = ()
    lamps: Lamps | None = Field(default=None, description="the lamp panel (docs/lamps.md); None: "
                                "lamps are switched by hand or by the simulator")
    alarms: AlarmLimits = Field(default_factory=AlarmLimits, description="limits that raise alarms")

    @model_validator(mode="after")
    def _references(self) -> PlantConfig:
        # Messages start with the key path: pydantic reports model-level errors at the top level.
        for kind, items in (("targets", self.targets), ("light_sources", self.light_sources),
                            ("heliostats", self.heliostats), ("person_zones", self.person_zones)):
            ids = [i.id for i in items]
            for index, item_id in enumerate(ids):
                if item_id in ids[:index]:
                    raise ValueError(f"{kind}[{index}].id: duplicate id {item_id!r}")
        if self.calibration.light_source not in {s.id for s in self.light_sources}:
            raise ValueError(f"calibration.light_source: {self.calibration.light_source!r} "
                             "is not the id of any entry of light_sources")
        lamps = {s.id for s in self.light_sources if s.kind == "lamp"}
        for index, lamp in enumerate(self.calibration.lamps):
            if lamp not in lamps:
                raise ValueError(f"calibration.lamps[{index}]: {lamp!r} is not the id of a lamp "
                                 "of light_sources")
            if lamp in self.calibration.lamps[:index]:
                raise ValueError(f"calibration.lamps[{index}]: {lamp!r} is listed twice")
        if self.calibration.beams_per_target > 1:
            sun = [s for s in (self.calibration.light_source, *self.calibration.lamps)
                   if s not in lamps]
            if sun:
                k = self.calibration.beams_per_target
                raise ValueError(f"calibration.beams_per_target: {k} beams on one target need lamps; "
                                 f"light source {sun[0]!r} is the sun (one concentrated sunlight beam "
                                 "per target)")
        if self.calibration.target not in {t.id for t in self.targets}:
            raise ValueError(f"calibration.target: {self.calibration.target!r} "
                             "is not the id of any entry of targets")
        for index, tid in enumerate(self.calibration.targets):
            if tid not in {t.id for t in self.targets} or tid in self.calibration.targets[:index]:
                raise ValueError(f"calibration.targets[{index}]: {tid!r} is not the id of an entry of "
                                 "targets, or is listed twice")
        seen: dict[tuple, str] = {}
        for index, h in enumerate(self.heliostats):
            link = h.link
            if link.kind == "none":  # reaches nothing, so shares nothing
                continue
            key = (*link.bus_key, link.station)
            if key in seen:
                raise ValueError(f"heliostats[{index}].link: heliostats {seen[key]!r} and {h.id!r} "
                                 f"share the link {key}")
            seen[key] = h.id
        if self.lamps is not None:
            needed = [lamp for lamp in (*self.calibration.planned_lamps(), self.calibration.light_source)
                      if lamp in lamps]
            by_command = {t.id for t in self.targets
                          if (cam := t.camera or self.camera).registration is not None
                          and cam.registration.lamp_command}
            check_channels(self.lamps, lamps, {t.id for t in self.targets}, needed, by_command)
        return self

    def heliostat(self, hid: str) -> Heliostat:
        return _by_id(self.heliostats, hid, "heliostat")

    def target(self, tid: str | None = None) -> Target:
        return _by_id(self.targets, tid or self.calibration.target, "target")

    def camera_of(self, tid: str | None = None) -> Camera:
        """The camera looking at target ``tid`` (default: the calibration target): its own, else
        the top-level ``camera``."""
        return self.target(tid).camera or self.camera

    def for_target(self, tid: str) -> PlantConfig:
        """This configuration as seen by the pipeline of target ``tid``: it is the calibration
        target and its camera the camera (the other targets stay listed for beam safety)."""
        return self.model_copy(update={"camera": self.camera_of(tid),
                                       "calibration": self.calibration.model_copy(update={"target": tid})})

    def light_source(self, sid: str | None = None) -> SunSource | LampSource:
        return _by_id(self.light_sources, sid or self.calibration.light_source, "light source")


_INDEX: dict[int, tuple[tuple, dict]] = {}  # id(items) -> (items, {id: entry}): a large field's lookups


def _by_id(items, item_id: str, what: str):
    """The entry of ``items`` whose ``id`` is ``item_id``; ConfigError naming the known ids (a
    field of thousands of heliostats is looked up through an index, built once per tuple)."""
    if len(items) > 16:
        hit = _INDEX.get(id(items))
        if hit is None or hit[0] is not items:
            if len(_INDEX) > 64:
                _INDEX.clear()
            hit = _INDEX[id(items)] = (items, {it.id: it for it in items})
        if item_id in hit[1]:
            return hit[1][item_id]
    else:
        for it in items:
            if it.id == item_id:
                return it
    known = [it.id for it in items]
    listed = ", ".join(known[:20]) + (f", … ({len(known)} in all)" if len(known) > 20 else "")
    raise ConfigError(f"no {what} {item_id!r} in the configuration (known: {listed})")


def parse_config(data: object, source: str = "<config>") -> PlantConfig:
    """Validate an already-parsed YAML document; errors name ``source`` and the key path. A
    ``field`` section's file is read relative to ``source``'s folder."""
    if data is None:
        raise ConfigError(f"{source}: the configuration is empty (see docs/configuration.md)")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: (top level): must be a mapping of sections, "
                          f"got {type(data).__name__}")
    # Top-level "x-" keys hold YAML anchors shared by several entries (as in compose files).
    data = {k: v for k, v in data.items() if not str(k).startswith("x-")}
    if "field" in data and data["field"] is not None:
        data = _with_field(data, source)
    data = _with_prior_path(data, source)
    try:
        return PlantConfig.model_validate(data)
    except ValidationError as exc:
        raise _config_error(exc, source) from None


def _with_prior_path(data: dict, source: str) -> dict:
    """``data`` with ``calibration.model.field_prior`` taken relative to ``source``'s folder."""
    cal = data.get("calibration")
    model = cal.get("model") if isinstance(cal, dict) else None
    path = model.get("field_prior") if isinstance(model, dict) else None
    if not isinstance(path, str) or not path or Path(path).is_absolute():
        return data
    resolved = str(Path(source).resolve().parent / path)
    return {**data, "calibration": {**data["calibration"], "model": {**model, "field_prior": resolved}}}


def _with_field(data: dict, source: str) -> dict:
    """``data`` with the heliostats of its ``field`` section's file."""
    if "heliostats" in data:
        raise ConfigError(f"{source}: heliostats: given both inline and in field.file; keep one")
    try:
        spec = FieldFile.model_validate(data["field"])
    except ValidationError as exc:
        raise _config_error(exc, source, ("field",)) from None
    return {**data, "field": spec, "heliostats": load_field(spec, source)}


def _config_error(exc: ValidationError, source: str, prefix: tuple = ()) -> ConfigError:
    """The one line of pydantic's first error: file, key path (under ``prefix``), rule."""
    err = exc.errors()[0]
    rule = err["msg"].removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":
        rule = "unknown key" + did_you_mean(str(err["loc"][-1]), PlantConfig)
    elif err["type"] == "missing":
        rule = "required key is missing"
    more = f" (and {len(exc.errors()) - 1} more problems)" if len(exc.errors()) > 1 else ""
    if not err["loc"] and err["type"] == "value_error" and not prefix:
        return ConfigError(f"{source}: {rule}{more}")  # the rule names its key path
    return ConfigError(f"{source}: {key_path(prefix + tuple(err['loc']))}: {rule}{more}")


def load_config(path: str | Path) -> PlantConfig:
    """Read and validate a plant configuration YAML file.

    Raises ConfigError (exit status 2) naming the file, key path and rule on any problem.
    """
    p = Path(path)
    try:
        data = parse_yaml(read_text(p, "configuration"), str(p))
    except InputError as exc:
        large = p.is_file() and p.stat().st_size > MAX_BYTES
        hint = " (a large field's heliostats go in a field file: docs/configuration.md)" if large else ""
        raise ConfigError(f"{exc}{hint}") from None
    return parse_config(data, str(p))
