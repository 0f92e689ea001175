"""The field file: a plant's heliostats in a CSV of their own, referenced by the configuration's
``field`` section (docs/configuration.md, "The field in its own file").

One row per heliostat, a header first (columns in any order)::

    id,east_m,north_m,up_m,kinematics,bus,station,focal_length_m
    H0001,-22.5,40.0,2.0,aa39,bus1,1,53.8

``kinematics`` names an entry of ``field.kinematics`` (mirror and axes), ``bus`` an entry of
``field.buses`` and ``station`` the heliostat's address or unit id on it; ``focal_length_m``
(optional, may be empty) replaces the design's mirror focal length. Every cell is checked by
the rules of an inline heliostat; a bad row ends in one :class:`ConfigError` naming the file,
the line and the column. :func:`config_sha256`, which names the configuration a campaign ran
with, covers the field file too.
"""

from __future__ import annotations

import csv
import hashlib
import io
from pathlib import Path

from pydantic import ValidationError

from controller.errors import ConfigError, InputError
from controller.heliostat_config import FieldFile, Heliostat, Mirror
from controller.io.files import read_bytes
from controller.io.text_numbers import is_ascii_index
from controller.io.yaml_files import parse_yaml

COLUMNS = ("id", "east_m", "north_m", "up_m", "kinematics", "bus", "station")
OPTIONAL = ("focal_length_m",)
MAX_BYTES = 64 << 20  # ~1 million rows; the largest fields have under 100,000 heliostats
_POSITION = ("east_m", "north_m", "up_m")


def field_path(file: str, config_source: str) -> Path:
    """Where ``field.file`` is: relative paths start at the configuration's folder."""
    p = Path(file)
    return p if p.is_absolute() else Path(config_source).parent / p


def load_field(spec: FieldFile, config_source: str) -> tuple[Heliostat, ...]:
    """The heliostats of ``spec``'s file, in row order; ConfigError naming file, line and column."""
    path = field_path(spec.file, config_source)
    try:
        data = read_bytes(path, "field file", MAX_BYTES)
        text = data.decode("utf-8-sig")  # a spreadsheet's export may start with a byte-order mark
    except InputError as exc:
        raise ConfigError(f"{exc} (field.file of {config_source})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text field file (byte {exc.start} is not UTF-8)") from None
    return _Rows(spec, path).read(text)


def config_sha256(path: str | Path) -> str:
    """SHA-256 of a configuration file's bytes, followed by its field file's when it has one:
    which configuration a campaign was started with."""
    try:
        raw = read_bytes(path, "configuration")
        digest = hashlib.sha256(raw)
        file = _field_file_of(raw, digest.hexdigest(), str(path))
        if file is not None:
            digest.update(read_bytes(field_path(file, str(path)), "field file", MAX_BYTES))
    except InputError as exc:
        raise ConfigError(str(exc)) from None
    return digest.hexdigest()


_FIELD_FILES: dict[str, str | None] = {}  # sha256 of a configuration -> its field.file


def _field_file_of(raw: bytes, sha: str, source: str) -> str | None:
    """``field.file`` of a configuration's bytes ``raw`` (SHA-256 ``sha``), or None; parsed once
    per content (a night hashes its configuration for every campaign it opens)."""
    if sha not in _FIELD_FILES:
        data = parse_yaml(raw.decode("utf-8", errors="replace"), source) if b"field" in raw else None
        field = data.get("field") if isinstance(data, dict) else None
        file = field.get("file") if isinstance(field, dict) else None
        _FIELD_FILES[sha] = file if isinstance(file, str) and file else None
    return _FIELD_FILES[sha]


class _Rows:
    """One pass over a field file's rows, with what earlier rows claimed (ids, links)."""

    def __init__(self, spec: FieldFile, path: Path) -> None:
        self.spec = spec
        self.path = path
        self.ids: dict[str, int] = {}
        self.links: dict[tuple, tuple[str, int]] = {}
        self.mirrors: dict[tuple[str, str], Mirror] = {}

    def fail(self, line: int, column: str | None, rule: str) -> ConfigError:
        where = f"line {line}, column {column}" if column else f"line {line}"
        return ConfigError(f"{self.path}: {where}: {rule}")

    def read(self, text: str) -> tuple[Heliostat, ...]:
        reader = csv.reader(io.StringIO(text, newline=""))
        out: list[Heliostat] = []
        header: list[str] | None = None
        line = 1  # where the row being read starts
        try:
            for row in reader:
                if any("\n" in cell or "\r" in cell for cell in row):
                    raise self.fail(line, None, "a quoted cell runs over several lines (a quote not closed?)")
                line = reader.line_num + 1
                if not any(cell.strip() for cell in row):
                    continue
                if header is None:
                    header = self.header(row, reader.line_num)
                    continue
                if len(row) != len(header):
                    raise self.fail(reader.line_num, None, f"{len(row)} field{'s' * (len(row) != 1)}, the "
                                    f"header has {len(header)}")
                out.append(self.heliostat(dict(zip(header, (c.strip() for c in row), strict=True)),
                                          reader.line_num))
        except csv.Error as exc:
            raise self.fail(reader.line_num, None, f"not CSV: {exc}") from None
        if not out:
            raise ConfigError(f"{self.path}: no heliostat rows (a header, then one row per heliostat)")
        return tuple(out)

    def header(self, row: list[str], line: int) -> list[str]:
        names = [c.strip() for c in row]
        for name in names:
            if name not in COLUMNS + OPTIONAL:
                raise self.fail(line, name, f"unknown column (the columns: {', '.join(COLUMNS + OPTIONAL)})")
            if names.count(name) > 1:
                raise self.fail(line, name, "column given twice")
        for name in COLUMNS:
            if name not in names:
                raise self.fail(line, name, f"required column is missing (header: {', '.join(names)})")
        return names

    def heliostat(self, cells: dict[str, str], line: int) -> Heliostat:
        hid = cells["id"]
        if not hid:
            raise self.fail(line, "id", "empty")
        if hid in self.ids:
            raise self.fail(line, "id", f"duplicate id {hid!r} (first at line {self.ids[hid]})")
        kin = self.spec.kinematics.get(cells["kinematics"])
        if kin is None:
            raise self.fail(line, "kinematics", f"{cells['kinematics']!r} is not a name of field.kinematics "
                            f"(known: {', '.join(sorted(self.spec.kinematics))})")
        bus = self.spec.buses.get(cells["bus"])
        if bus is None:
            raise self.fail(line, "bus", f"{cells['bus']!r} is not a name of field.buses "
                            f"(known: {', '.join(sorted(self.spec.buses))})")
        if not is_ascii_index(cells["station"]):
            raise self.fail(line, "station", f"{cells['station']!r} is not a whole number (ASCII digits)")
        station = int(cells["station"])
        if not 1 <= station <= 247:
            raise self.fail(line, "station", f"{station} is not a bus address or unit id (1 … 247)")
        link = bus.link(station)
        key = (*link.bus_key, station)
        if key in self.links:
            other, first = self.links[key]
            raise self.fail(line, "station", f"heliostats {other!r} (line {first}) and {hid!r} share the "
                            f"link {key}")
        try:
            h = Heliostat.model_validate({
                "id": hid, "position_enu_m": tuple(cells[c] for c in _POSITION),
                "mirror": self.mirror(cells["kinematics"], kin.mirror, cells.get("focal_length_m", ""), line),
                "axes": kin.axes, "link": link, "concentrator_translation_m": kin.concentrator_translation_m})
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = err["loc"]
            column = _POSITION[loc[1]] if loc[:1] == ("position_enu_m",) and len(loc) > 1 else str(loc[0])
            raise self.fail(line, column, err["msg"]) from None
        self.ids[hid] = line
        self.links[key] = (hid, line)
        return h

    def mirror(self, design: str, base: Mirror, focal: str, line: int) -> Mirror:
        """The design's mirror, with the row's focal length when it gives one (one model per
        distinct value: a field's rows share a few)."""
        if not focal:
            return base
        key = (design, focal)
        if key not in self.mirrors:
            try:
                self.mirrors[key] = Mirror.model_validate({**base.model_dump(), "focal_length_m": focal})
            except ValidationError as exc:
                raise self.fail(line, "focal_length_m", exc.errors()[0]["msg"]) from None
        return self.mirrors[key]

