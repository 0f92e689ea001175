"""Files of the error library: the manifest CSV that lists reference images, and the library
YAML (format in :mod:`controller.recognition.library`).

Manifest (CSV, header required): ``image,label,az_deg,el_deg``. ``az_deg``/``el_deg`` are
optional (columns may be absent or cells empty); image paths are relative to the manifest.
Further columns (e.g. ``heliostat,source,slant_m,magnitude`` of a rendered error set) are kept
as the row's ``extra`` and become the library entry's ``params``.
Images are merged HDR (``.npy`` / float ``.tiff``) or single grey PNG/TIFF.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from controller.errors import InputError
from controller.io.images import read_image, write_atomic
from controller.io.text_numbers import parse_float
from controller.io.yaml_files import load_yaml, read_text
from controller.recognition.library import Library, build_library
from controller.recognition.library_doc import library_from_dict, library_to_dict

MAX_MANIFEST_ROWS = 100_000
MAX_MANIFEST_BYTES = 64 << 20  # 100 000 rows of a path, a label and two angles


@dataclass(frozen=True)
class ManifestRow:
    image: Path
    label: str
    az_deg: float | None = None
    el_deg: float | None = None
    line: int = 0
    extra: dict[str, str] = field(default_factory=dict)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _opt_float(value: str | None, where: str, key: str) -> float | None:
    if value is None or value.strip() == "":
        return None
    try:
        v = parse_float(value.strip(), key)
    except InputError:
        raise InputError(f"{where}: {key} is not a number: {value!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{where}: {key} must be finite, got {value!r}")
    return v


MANIFEST_HEADER = ("image", "label", "az_deg", "el_deg")


def write_manifest(path: str | Path, rows: list[tuple[str, ...]] | list[list[str]],
                   header: tuple[str, ...] = MANIFEST_HEADER) -> None:
    """Write a manifest CSV (``image,label,az_deg,el_deg[,...]``, paths relative to it) atomically."""
    if tuple(header[:4]) != MANIFEST_HEADER:
        raise ValueError(f"a manifest header starts with {','.join(MANIFEST_HEADER)}")

    def writer(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(list(header))
            w.writerows(rows)

    write_atomic(path, writer)


def read_manifest(path: str | Path) -> list[ManifestRow]:
    """Read a manifest CSV; errors name the file and line."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        raise InputError(f"{p}: manifest not found")
    try:
        with io.StringIO(read_text(p, "manifest", MAX_MANIFEST_BYTES), newline="") as f:
            reader = csv.DictReader(f)
            fields = [c.strip() for c in (reader.fieldnames or [])]
            missing = {"image", "label"} - set(fields)
            if missing:
                raise InputError(f"{p}: header must contain image,label "
                                 f"(missing {', '.join(sorted(missing))})")
            rows = []
            for i, raw in enumerate(reader, start=2):
                if len(rows) >= MAX_MANIFEST_ROWS:
                    raise InputError(f"{p}: more than {MAX_MANIFEST_ROWS} rows")
                rec = {(k or "").strip(): (v or "").strip() for k, v in raw.items() if k is not None}
                where = f"{p}:{i}"
                if not rec.get("image"):
                    raise InputError(f"{where}: empty image path")
                if not rec.get("label"):
                    raise InputError(f"{where}: empty label")
                rows.append(ManifestRow(
                    image=(p.parent / rec["image"]), label=rec["label"],
                    az_deg=_opt_float(rec.get("az_deg"), where, "az_deg"),
                    el_deg=_opt_float(rec.get("el_deg"), where, "el_deg"), line=i,
                    extra={k: v for k, v in rec.items() if k not in MANIFEST_HEADER and k and v},
                ))
    except UnicodeDecodeError:
        raise InputError(f"{p}: manifest is not UTF-8 text") from None
    except csv.Error as exc:
        raise InputError(f"{p}: malformed CSV ({exc})") from None
    if not rows:
        raise InputError(f"{p}: manifest has no rows")
    return rows


def _params(extra: dict[str, str]) -> dict | None:
    """Extra manifest columns as entry params: numbers where they parse, else text."""
    out: dict = {}
    for k, v in extra.items():
        try:
            out[k] = parse_float(v, k)
        except InputError:
            out[k] = v
    return out or None


def build_library_from_manifest(manifest: str | Path, kind: str = "hu", threshold: float = 0.5,
                                progress: Callable[[int, int], None] | None = None,
                                whiten: bool | None = None, widen: Sequence[float] | None = None) -> Library:
    """Read every manifest image and build the :class:`Library` (nothing is written); errors
    name the manifest line. Extra columns become the entries' ``params``."""
    rows = read_manifest(manifest)
    images = []
    for row in rows:
        try:
            images.append(read_image(row.image))
        except InputError as exc:
            raise InputError(f"{Path(manifest)}:{row.line}: {exc}") from None
    names = [str(r.image) for r in rows]
    try:
        return build_library(images, [r.label for r in rows], kind=kind, threshold=threshold,
                             az_deg=[r.az_deg for r in rows], el_deg=[r.el_deg for r in rows],
                             sha256=[sha256_file(r.image) for r in rows], names=names,
                             params=[_params(r.extra) for r in rows], whiten=whiten, widen=widen,
                             progress=progress)
    except InputError as exc:
        line = next((r.line for r in rows if str(exc).startswith(f"{r.image}:")), None)
        raise InputError(f"{Path(manifest)}:{line}: {exc}" if line else str(exc)) from None


def save_library(lib: Library, path: str | Path) -> None:
    """Write the library YAML atomically."""
    text = yaml.safe_dump(library_to_dict(lib), sort_keys=False)
    write_atomic(path, lambda t: t.write_text(text, encoding="utf-8"))


def load_library(path: str | Path) -> Library:
    """Read and validate a library YAML; errors name the file and key."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        raise InputError(f"{p}: library not found")
    return library_from_dict(load_yaml(p, "library"), str(p))


def load_library_if_present(path: str | Path | None) -> Library | None:
    """The library at ``path``, or None when no path is given or no file is there yet (storing a
    reference case creates it); anything else there (a FIFO, a folder) is refused, naming it."""
    if not path:
        return None
    p = Path(path)
    return load_library(p) if p.exists() or p.is_symlink() else None


def add_reference(library_path: str | Path, label: str, hdr, hu, *, source: str, threshold: float) -> dict:
    """Store a captured HDR frame as a new reference case ``label`` of the library at
    ``library_path`` (created when missing): the frame goes to ``references/`` beside it, the
    entry into the library, a row into its manifest (``<stem>-manifest.csv``). Returns what
    was written."""
    from controller.io.images import write_float_image
    from controller.recognition.library import Entry, hu_features

    if not label or any(c in label for c in ",\n"):
        raise InputError(f"reference label must be a non-empty word without commas, got {label!r}")
    lib_path = Path(library_path)
    lib = load_library(lib_path) if lib_path.is_file() else Library(features="log-hu", threshold=threshold,
                                                                      entries=[])
    n = sum(1 for e in lib.entries if e.label == label)
    img = lib_path.parent / "references" / f"{source}-{label}-{n:02d}.npy"
    write_float_image(img, hdr)
    # A multi-threshold library describes the frame itself; the others take the given Hu moments.
    feats = hu_features(lib.describe(hdr) if lib.features not in ("hu", "log-hu") else hu, lib.features)
    entry = Entry(label=label, features=feats, sha256=sha256_file(img), image=str(img))
    lib.entries.append(entry)
    save_library(lib, lib_path)
    manifest = lib_path.with_name(lib_path.stem + "-manifest.csv")
    rows = []
    if manifest.is_file():
        with open(manifest, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))[1:]
    rows.append([str(img.relative_to(manifest.parent)), label, "", ""])
    write_manifest(manifest, rows)
    return {"label": label, "image": str(img), "sha256": entry.sha256, "library": str(lib_path),
            "entries": len(lib.entries), "manifest": str(manifest)}
