"""The one rule every number of the plant configuration obeys: finite, and inside a stated
physical range (docs/configuration.md, "Numeric keys and their ranges").

Every section of the configuration derives from :class:`Section`, which refuses NaN and ±inf
for every float it holds (pydantic's ``allow_inf_nan=False``); every numeric key carries both a
lower and an upper bound, given by its ``Field`` or by one of the bounded types below.
``tests/test_config_ranges.py`` walks the schema and fails on a numeric key without both bounds,
so a new key cannot reach a drive, a plan or a report unbounded.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field
from pydantic.fields import FieldInfo

# The largest field in operation is about 1.5 km in radius; 10 km about the plant origin holds
# any field with margin while refusing a misplaced decimal point or a unit mix-up (mm for m).
MAX_DISTANCE_M = 10_000.0
MAX_HEIGHT_M = 2_000.0  # up: towers are under 300 m; terrain steps stay well below this

INT32_MAX = 2**31 - 1  # steps travel as int32 on both wire protocols (PROTOCOL.md, MODBUS.md)
MAX_SENSOR_PX = 16384


class Section(BaseModel):
    """Base of every configuration section: unknown keys refused, frozen, only finite floats."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


East = Annotated[float, Field(ge=-MAX_DISTANCE_M, le=MAX_DISTANCE_M)]
North = Annotated[float, Field(ge=-MAX_DISTANCE_M, le=MAX_DISTANCE_M)]
Up = Annotated[float, Field(ge=-MAX_HEIGHT_M, le=MAX_HEIGHT_M)]
Position = tuple[East, North, Up]
"""A point in local ENU metres about the plant origin."""

Component = Annotated[float, Field(ge=-1, le=1)]
Direction = tuple[Component, Component, Component]
"""A direction's components (checked to be a unit vector where one is required)."""

Pixel = Annotated[float, Field(ge=0, le=MAX_SENSOR_PX)]
PixelOffset = Annotated[int, Field(ge=0, le=MAX_SENSOR_PX)]
RadialDistortion = Annotated[float, Field(ge=-1000, le=1000)]  # k1, k2 (OpenCV, normalised radius)
TangentialDistortion = Annotated[float, Field(ge=-1, le=1)]  # p1, p2
Steps = Annotated[int, Field(ge=0, le=INT32_MAX)]
Baud = Annotated[int, Field(ge=300, le=4_000_000)]
PriorSigma = Annotated[float, Field(gt=0, le=1000)]


@dataclass(frozen=True)
class NumericKey:
    """One numeric key of the schema and its range. ``path`` is written as in the file, with
    ``[]`` for any entry of a list, ``(kind)`` for the entry type a ``kind:`` (or a
    ``driver:``) selects and
    ``.<key>`` for any key of a mapping of numbers (``calibration.model.prior_sigma.<key>``)."""

    path: str
    integer: bool
    lower: float | None
    lower_open: bool
    upper: float | None
    upper_open: bool

    def range_text(self) -> str:
        """The range as written in docs/configuration.md: ``[0, 50]``, ``(0, 1]``."""
        def num(x: float | None) -> str:
            if x is None:
                return "?"
            if abs(x) == math.pi:
                return "−π" if x < 0 else "π"
            text = str(int(x)) if self.integer or x == int(x) and abs(x) < 1e6 else f"{x:g}"
            return text.replace("e+0", "e").replace("e+", "e").replace("-", "−")
        return (("(" if self.lower_open else "[") + f"{num(self.lower)}, {num(self.upper)}"
                + (")" if self.upper_open else "]"))


def numeric_keys(model: type[BaseModel]) -> list[NumericKey]:
    """Every numeric key under ``model``, breadth first (a section reached twice, as the camera
    of a target and the top-level camera, is listed where it is nearest the top)."""
    out: list[NumericKey] = []
    seen = {model}
    queue: deque[tuple[type[BaseModel], str]] = deque([(model, "")])
    while queue:
        section, prefix = queue.popleft()
        for name, field in section.model_fields.items():
            path = f"{prefix}.{name}" if prefix else name
            _walk(field.annotation, list(field.metadata), path, out, queue, seen)
    return out


def _walk(tp: Any, meta: list, path: str, out: list[NumericKey], queue: deque, seen: set) -> None:
    origin, args = get_origin(tp), get_args(tp)
    if origin is Annotated:
        inner = [c for a in args[1:] for c in (a.metadata if isinstance(a, FieldInfo) else [a])]
        _walk(args[0], meta + inner, path, out, queue, seen)
    elif origin in (Union, UnionType):
        for arg in args:
            _walk(arg, meta, path, out, queue, seen)
    elif origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            _walk(args[0], [], f"{path}[]", out, queue, seen)
        else:
            for i, arg in enumerate(args):
                _walk(arg, [], f"{path}[{i}]", out, queue, seen)
    elif origin is dict:
        _walk(args[1], [], f"{path}.<key>", out, queue, seen)
    elif isinstance(tp, type) and issubclass(tp, BaseModel):
        # The entry type a ``kind:`` (links, light sources) or ``driver:`` (lamps) selects.
        kind = tp.model_fields.get("kind") or tp.model_fields.get("driver")
        if kind is not None and get_origin(kind.annotation) is Literal:
            path = f"{path}({get_args(kind.annotation)[0]})"
        if tp not in seen:
            seen.add(tp)
            queue.append((tp, path))
    elif tp in (int, float):
        def bound(*names: str) -> tuple[float | None, bool]:
            for c in meta:
                for open_, attr in zip((False, True), names, strict=True):
                    if getattr(c, attr, None) is not None:
                        return getattr(c, attr), open_
            return None, False
        lower, lower_open = bound("ge", "gt")
        upper, upper_open = bound("le", "lt")
        out.append(NumericKey(path, tp is int, lower, lower_open, upper, upper_open))
