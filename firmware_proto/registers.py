"""The Modbus register map (``registers.yaml``): loader, validation and word encoding.

Pure code: no I/O beyond reading the YAML file. Both the simulated Modbus actuator and the
Modbus drive build their requests from this map, so the map is the single source of the
addresses, types, word orders, command codes and status bits.

Conventions: addresses are 0-based protocol addresses; a 32-bit value occupies two 16-bit
registers, high word first for ``word_order: big`` (Modbus byte order inside each word is
always big-endian); engineering value = raw integer * ``scale``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

DEFAULT_MAP = Path(__file__).with_name("registers.yaml")

TABLES = ("holding", "input")
TYPES = {"uint16": (1, False), "int16": (1, True), "uint32": (2, False), "int32": (2, True)}
ACCESS = ("r", "rw")
_KEYS = {"name", "table", "address", "type", "word_order", "scale", "unit", "access",
         "description", "codes", "bits"}


class RegisterMapError(ValueError):
    """The register map file is invalid; the message names the file and the entry."""


@dataclass(frozen=True)
class Register:
    """One named value in the map (one or two 16-bit registers)."""

    name: str
    table: str
    address: int
    type: str
    scale: float
    unit: str
    access: str
    word_order: str = "big"
    description: str = ""
    codes: Mapping[str, int] = field(default_factory=dict)
    bits: Mapping[str, int] = field(default_factory=dict)

    @property
    def count(self) -> int:
        """Number of 16-bit registers the value occupies (1 or 2)."""
        return TYPES[self.type][0]

    @property
    def signed(self) -> bool:
        return TYPES[self.type][1]

    @property
    def end(self) -> int:
        """One past the last register address."""
        return self.address + self.count

    @property
    def writable(self) -> bool:
        return self.access == "rw"

    def limits(self) -> tuple[int, int]:
        """Inclusive range of the raw integer."""
        nbits = 16 * self.count
        if self.signed:
            return -(1 << (nbits - 1)), (1 << (nbits - 1)) - 1
        return 0, (1 << nbits) - 1

    def encode(self, value: int) -> list[int]:
        """Raw integer -> register words in wire order. Raises ValueError when out of range."""
        if not isinstance(value, int) or isinstance(value, bool):
            raise ValueError(f"{self.name}: value must be an integer, got {value!r}")
        lo, hi = self.limits()
        if not lo <= value <= hi:
            raise ValueError(f"{self.name}: {value} does not fit {self.type} [{lo}, {hi}]")
        u = value & ((1 << (16 * self.count)) - 1)
        if self.count == 1:
            return [u]
        words = [(u >> 16) & 0xFFFF, u & 0xFFFF]
        return words if self.word_order == "big" else words[::-1]

    def decode(self, words: Sequence[int]) -> int:
        """Register words in wire order -> raw integer (two's complement for signed types)."""
        if len(words) != self.count:
            raise ValueError(f"{self.name}: expected {self.count} words, got {len(words)}")
        for w in words:
            if not 0 <= w <= 0xFFFF:
                raise ValueError(f"{self.name}: register word {w!r} is not 16-bit")
        if self.count == 1:
            u = words[0]
        else:
            hi, lo = (words[0], words[1]) if self.word_order == "big" else (words[1], words[0])
            u = (hi << 16) | lo
        nbits = 16 * self.count
        if self.signed and u >= 1 << (nbits - 1):
            u -= 1 << nbits
        return u

    def to_engineering(self, raw: int) -> float:
        return raw * self.scale


@dataclass(frozen=True)
class RegisterMap:
    """All registers of one map version, looked up by name or by table and address."""

    version: int
    registers: tuple[Register, ...]
    device_type: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_name", {r.name: r for r in self.registers})

    def __getitem__(self, name: str) -> Register:
        try:
            return self._by_name[name]  # type: ignore[attr-defined]
        except KeyError:
            raise KeyError(f"no register named {name!r} in the map") from None

    def __contains__(self, name: str) -> bool:
        return name in self._by_name  # type: ignore[attr-defined]

    def table(self, table: str) -> list[Register]:
        """Registers of one table, by address."""
        return sorted((r for r in self.registers if r.table == table), key=lambda r: r.address)

    def at(self, table: str, address: int) -> Register | None:
        """The register that occupies ``address`` (first or second word), or None."""
        for r in self.registers:
            if r.table == table and r.address <= address < r.end:
                return r
        return None

    def span(self, first: str, last: str) -> tuple[int, int]:
        """(address, count) covering registers ``first`` .. ``last`` of one table."""
        a, b = self[first], self[last]
        if a.table != b.table or b.end <= a.address:
            raise ValueError(f"{first}..{last} is not an address range of one table")
        return a.address, b.end - a.address

    def encode(self, values: Mapping[str, int]) -> tuple[int, list[int]]:
        """Encode named values of one table that form a contiguous block.

        Returns (start address, words). Raises ValueError naming the register on a gap,
        a mixed table or a value that does not fit."""
        regs = sorted((self[n] for n in values), key=lambda r: r.address)
        if not regs:
            raise ValueError("nothing to encode")
        words: list[int] = []
        for prev, reg in zip([None, *regs[:-1]], regs, strict=True):
            if prev is not None and (reg.table != prev.table or reg.address != prev.end):
                raise ValueError(f"{prev.name} and {reg.name} are not adjacent registers")
            words += reg.encode(values[reg.name])
        return regs[0].address, words

    def decode(self, table: str, address: int, words: Sequence[int]) -> dict[str, int]:
        """Decode every register lying wholly inside the block read from ``address``."""
        end = address + len(words)
        return {r.name: r.decode(words[r.address - address:r.end - address])
                for r in self.table(table) if address <= r.address and r.end <= end}

    def code(self, register: str, name: str) -> int:
        """Value of an enumerated code, e.g. ``code("command", "move")``."""
        return self[register].codes[name]

    def bit(self, register: str, name: str) -> int:
        """Mask of a named bit, e.g. ``bit("status_bits", "moving")``."""
        return 1 << self[register].bits[name]


def _entry(raw: object, where: str) -> Register:
    if not isinstance(raw, dict):
        raise RegisterMapError(f"{where}: must be a mapping, got {type(raw).__name__}")
    if "name" in raw:
        where = f"{where} ({raw['name']})"
    unknown = set(raw) - _KEYS
    if unknown:
        raise RegisterMapError(f"{where}: unknown key(s) {sorted(unknown)}")
    for key in ("name", "table", "address", "type", "scale", "unit", "access"):
        if key not in raw:
            raise RegisterMapError(f"{where}: missing key {key!r}")
    name = raw["name"]
    if raw["table"] not in TABLES:
        raise RegisterMapError(f"{where}: table must be one of {TABLES}, got {raw['table']!r}")
    if raw["type"] not in TYPES:
        raise RegisterMapError(f"{where}: type must be one of {tuple(TYPES)}, got {raw['type']!r}")
    addr = raw["address"]
    if not isinstance(addr, int) or isinstance(addr, bool) or not 0 <= addr <= 0xFFFF:
        raise RegisterMapError(f"{where}: address must be an integer 0..65535, got {addr!r}")
    if raw["access"] not in ACCESS:
        raise RegisterMapError(f"{where}: access must be one of {ACCESS}, got {raw['access']!r}")
    if raw["table"] == "input" and raw["access"] != "r":
        raise RegisterMapError(f"{where}: input registers are read-only (access: r)")
    wide = TYPES[raw["type"]][0] == 2
    if wide and raw.get("word_order") not in ("big", "little"):
        raise RegisterMapError(f"{where}: a 32-bit register needs word_order big or little")
    if not wide and "word_order" in raw:
        raise RegisterMapError(f"{where}: word_order applies only to 32-bit types")
    scale = raw["scale"]
    if not isinstance(scale, (int, float)) or isinstance(scale, bool) or scale == 0:
        raise RegisterMapError(f"{where}: scale must be a non-zero number, got {scale!r}")
    return Register(name=str(name), table=raw["table"], address=addr, type=raw["type"],
                    scale=float(scale), unit=str(raw["unit"]), access=raw["access"],
                    word_order=raw.get("word_order", "big"),
                    description=str(raw.get("description", "")),
                    codes=dict(raw.get("codes") or {}), bits=dict(raw.get("bits") or {}))


def parse_register_map(doc: object, source: str = "<map>") -> RegisterMap:
    """Validate a parsed YAML document into a :class:`RegisterMap`.

    Checks: known keys, tables, types, word order for (and only for) 32-bit types, unique
    names, no overlapping addresses within a table, input registers read-only."""
    if not isinstance(doc, dict) or not isinstance(doc.get("registers"), list):
        raise RegisterMapError(f"{source}: top level must be a mapping with a list 'registers'")
    regs = [_entry(raw, f"{source}: registers[{i}]") for i, raw in enumerate(doc["registers"])]
    seen: dict[str, int] = {}
    for i, r in enumerate(regs):
        if r.name in seen:
            raise RegisterMapError(f"{source}: registers[{i}]: duplicate name {r.name!r}")
        seen[r.name] = i
    for table in TABLES:
        ordered = sorted((r for r in regs if r.table == table), key=lambda r: r.address)
        for a, b in zip(ordered, ordered[1:], strict=False):
            if b.address < a.end:
                raise RegisterMapError(
                    f"{source}: {b.name} at {table} {b.address} overlaps {a.name} "
                    f"({table} {a.address}..{a.end - 1})")
    return RegisterMap(version=int(doc.get("map_version", 1)), registers=tuple(regs),
                       device_type=int(doc.get("device_type", 0)))


def load_register_map(path: str | Path = DEFAULT_MAP) -> RegisterMap:
    """Read and validate ``registers.yaml`` (default: the one next to this module)."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise RegisterMapError(f"{p}: cannot read: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise RegisterMapError(f"{p}: invalid YAML: {exc}") from None
    return parse_register_map(doc, str(p))
