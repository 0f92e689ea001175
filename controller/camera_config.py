"""The camera section of the plant configuration (``camera:``, docs/configuration.md and
docs/camera.md): the double-CCD camera, its two sensors and, for a GigE Vision camera, its
two imagers. Re-exported by :mod:`controller.config`, whose :func:`load_config` validates it.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from controller.config_rules import (
    MAX_SENSOR_PX,
    Pixel,
    PixelOffset,
    Position,
    RadialDistortion,
    Section,
    TangentialDistortion,
)
from controller.io.text_numbers import is_ascii_index

Vec3 = tuple[float, float, float]
_Model = Section  # as every configuration section (controller.config_rules)


class Sensor(_Model):
    name: str
    exposure_s: float = Field(gt=0, le=10)
    gain: float = Field(default=1.0, gt=0, le=10, description="relative gain (mismatch)")


class Gige(_Model):
    """The two GigE Vision imagers of the double-CCD camera, driven through Aravis
    (docs/camera.md). Frames are ``camera.width_px`` x ``camera.height_px`` at ``roi_offset_px``;
    exposures start at ``camera.sensors[i].exposure_s``."""

    low: str = Field(min_length=1, description="device id, serial or IP address of the LOW imager")
    high: str = Field(min_length=1, description="device id, serial or IP address of the HIGH imager")
    pixel_format: Literal["Mono8", "Mono12", "Mono16"] | None = Field(
        default=None, description="None: Mono<bit_depth>")
    gain: float | None = Field(default=None, ge=0, le=100, description="device gain of both imagers "
                               "(device units, usually dB); None: leave as set")
    roi_offset_px: tuple[PixelOffset, PixelOffset] = Field(default=(0, 0),
                                                           description="OffsetX, OffsetY of the ROI")
    trigger: str = Field(default="software", description="software, free (free-running) or LineN")
    frame_rate_hz: float = Field(default=30.0, gt=0, le=1000, description="with trigger: free")
    max_skew_ms: float = Field(default=1.0, gt=0, le=10000,
                               description="largest difference of the two frames' timestamps")
    timeout_ms: int = Field(default=2000, ge=10, le=600000, description="wait for one frame")
    buffers: int = Field(default=4, ge=2, le=256, description="stream buffers per imager")
    packet_size: int | None = Field(default=None, ge=576, le=16384,
                                    description="GVSP packet size, bytes; None: the device's")

    @field_validator("trigger")
    @classmethod
    def _trigger(cls, v: str) -> str:
        if v not in ("software", "free") and not (v.startswith("Line") and is_ascii_index(v[4:])):
            raise ValueError(f"{v!r}: must be software, free or LineN (a hardware input, e.g. Line1)")
        return v

    @model_validator(mode="after")
    def _two_imagers(self) -> Gige:
        if self.low == self.high:
            raise ValueError(f"low and high name the same imager {self.low!r}")
        return self


class CameraRegistration(_Model):
    """The camera model the controller is told (lab-calibrated intrinsics, nominal pose) and
    the target's surveyed fiducials it registers each sensor to (docs/camera.md, "Registration").
    Pose: the camera at ``camera.position_enu_m`` looking at ``look_at_enu_m`` (default the
    calibration target's centre), image x (column) level, ``roll_mrad`` about the line of sight."""

    focal_px: float = Field(gt=0, le=1e6, description="focal length, px (fx = fy)")
    principal_point_px: tuple[Pixel, Pixel] | None = Field(
        default=None, description="(cx, cy) px; None: the image centre")
    distortion: tuple[RadialDistortion, RadialDistortion, TangentialDistortion, TangentialDistortion] = Field(
        default=(0.0, 0.0, 0.0, 0.0), description="Brown-Conrady k1, k2, p1, p2 (OpenCV)")
    look_at_enu_m: Position | None = Field(default=None, description="None: the calibration target's centre")
    roll_mrad: float = Field(default=0.0, ge=-3142, le=3142)
    fiducials_enu_m: tuple[Position, ...] = Field(min_length=4, max_length=1000,
                                                  description="surveyed fiducials, m ENU")
    max_rms_px: float = Field(default=0.5, gt=0, le=10, description="refuse a registration above this")
    search_radius_px: float = Field(default=100.0, ge=5, le=2000,
                                    description="how far from its nominal pixel a fiducial is looked for")
    lamp_command: tuple[str, ...] | None = Field(
        default=None, min_length=1, max_length=32,
        description="argv of the plant's fiducial-lamp switch, run with 'on' or 'off' appended")

    @field_validator("fiducials_enu_m")
    @classmethod
    def _distinct(cls, v: tuple[Vec3, ...]) -> tuple[Vec3, ...]:
        if len(set(v)) != len(v):
            raise ValueError("fiducials must be distinct points")
        return v


class Camera(_Model):
    """The double-CCD prism camera. ``sensors[0]`` is the shorter exposure (LOW)."""

    sensors: tuple[Sensor, Sensor]
    width_px: int = Field(default=1024, gt=0, le=MAX_SENSOR_PX)
    height_px: int = Field(default=768, gt=0, le=MAX_SENSOR_PX)
    bit_depth: int = Field(default=8, ge=8, le=16)
    crf_file: str | None = None
    dark_offset_counts: float = Field(default=8.0, ge=0, le=255)
    read_noise_counts: float = Field(default=0.8, ge=0, le=50)
    full_well_electrons: float = Field(default=20000.0, gt=0, le=1e7)
    position_enu_m: Position | None = Field(default=None, description="camera position, m ENU")
    driver: Literal["gige", "file"] | None = Field(
        default=None, description="the field camera's driver (gige: section gige; file: the recorded "
        "pairs of manifest); None: no camera unless a command is given one (--camera-manifest, --simulate)")
    gige: Gige | None = None
    manifest: str | None = Field(default=None, description="recorded frame pairs (driver file)")
    registration: CameraRegistration | None = Field(
        default=None, description="register both sensors to the target's fiducials (docs/camera.md)")

    @model_validator(mode="after")
    def _low_first(self) -> Camera:
        if self.sensors[0].exposure_s > self.sensors[1].exposure_s:
            raise ValueError("sensors[0] must have the shorter exposure (LOW), sensors[1] the longer")
        if self.driver == "gige" and self.gige is None:
            raise ValueError("gige: required key is missing (driver is gige)")
        if self.driver == "file" and not self.manifest:
            raise ValueError("manifest: required key is missing (driver is file)")
        if self.gige is not None and self.gige.pixel_format is not None:
            bits = int(self.gige.pixel_format[4:])
            if bits != self.bit_depth:
                raise ValueError(f"gige.pixel_format: {self.gige.pixel_format} delivers {bits}-bit "
                                 f"pixels but bit_depth is {self.bit_depth}")
        elif self.gige is not None and self.bit_depth not in (8, 12, 16):
            raise ValueError(f"gige.pixel_format: required for bit_depth {self.bit_depth} "
                             "(GigE delivers Mono8, Mono12 or Mono16)")
        if self.registration is not None and self.position_enu_m is None:
            raise ValueError("registration: needs position_enu_m (the camera's nominal position)")
        return self

    def gige_pixel_format(self) -> str:
        """The GigE pixel format: ``gige.pixel_format`` or Mono<bit_depth>."""
        return (self.gige.pixel_format if self.gige and self.gige.pixel_format
                else f"Mono{self.bit_depth}")
