"""Reading and writing images at the edges of the pipeline.

Supported inputs: 8- or 16-bit grey PNG/TIFF (colour converted to grey), 32-bit float TIFF,
and ``.npy`` arrays (2-D, integer or float; never pickles), recognised by their first bytes and
bounded by :mod:`controller.io.image_headers` before decoding. Arrays are (rows, cols):
x = column, y = row.
Every failure raises :class:`controller.errors.InputError` naming the file.
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from controller.errors import InputError
from controller.io.files import read_bytes
from controller.io.image_headers import MAX_FILE_BYTES, check_header, image_header
from controller.io.png_stream import check_png


def read_image(path: str | Path) -> np.ndarray:
    """Read a 2-D grey image. Integer files keep their dtype; float data come back float32/64.

    The file's size and header (:mod:`controller.io.image_headers`) are checked before anything
    is decoded, so a hostile file costs at most its size plus the stated decoded limit."""
    p = Path(path)
    return decode_image(_read_bytes(p), str(p))


def decode_image(data: bytes, name: str, *, shape: tuple[int, int] | None = None,
                 written_here: bool = False) -> np.ndarray:
    """The 2-D grey image in ``data``, the bytes of the file ``name`` (read by a bounded reader,
    :func:`controller.io.files.read_bytes`), as :func:`read_image` returns it. With ``shape``
    (rows, cols) the header must claim exactly that size, checked before decoding.
    ``written_here``: the bytes are those this product wrote (their SHA-256 matched its record),
    so a PNG's stream check (:mod:`controller.io.png_stream`, about as long as the decode) is
    skipped."""
    header = image_header(data, name)
    check_header(header, name)
    if shape is not None and (header.height, header.width) != tuple(shape):
        raise InputError(f"{name}: {header.format.upper()} header claims {header.width}×{header.height} px, "
                         f"expected {shape[1]}×{shape[0]}")
    if header.format == "npy":
        try:
            img = np.load(io.BytesIO(data), allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise InputError(f"{name}: not a readable .npy array ({exc})") from None
    else:
        if header.format == "png" and not written_here:  # libpng would print a line of its own first
            check_png(data, name)
        # OpenCV logs its own warnings for corrupt files on stderr; our InputError says it once.
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:
            img = None
        finally:
            cv2.utils.logging.setLogLevel(level)
        if img is None:
            raise InputError(f"{name}: not a readable image (corrupt file or unsupported format)")
        if img.ndim == 3:
            if img.shape[2] == 4:
                img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
            elif img.shape[2] == 3:
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            else:
                img = img[:, :, 0]
    if img.ndim != 2:
        raise InputError(f"{name}: expected a 2-D grey image, got shape {img.shape}")
    if img.size == 0:
        raise InputError(f"{name}: image is empty")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise InputError(f"{name}: unsupported pixel type {img.dtype}")
    if np.issubdtype(img.dtype, np.floating) and not np.all(np.isfinite(img)):
        raise InputError(f"{name}: image contains NaN or infinite values")
    return img


def _read_bytes(p: Path) -> bytes:
    """The file's bytes: a regular file of at most :data:`MAX_FILE_BYTES` (controller.io.files)."""
    if not p.exists() and not p.is_symlink():
        raise InputError(f"{p}: image file not found")
    return read_bytes(p, "image file", MAX_FILE_BYTES)


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# Read once, at import: reading it means setting it, and for that instant every file another
# thread creates would get mode 0666 (the night's cycles write images side by side).
_UMASK = _read_umask()


def write_atomic(path: str | Path, writer) -> None:
    """Call ``writer(tmp_path)`` then rename onto ``path``, so nothing half-written remains."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=p.suffix, dir=p.parent)
    os.close(fd)
    try:
        writer(Path(tmp))
        # mkstemp creates 0600; give the file the mode a plain open() would (umask applied).
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """``data`` into ``path`` as :func:`write_atomic` writes, with fewer system calls: the
    temporary file is created with the mode a plain ``open()`` gives (``O_EXCL``, 0666 less the
    umask, so no ``chmod``), written through its one descriptor, then renamed. The folder is
    made only when it is missing (a night's archive writes two frames per measurement into a
    folder that exists after the first)."""
    p = Path(path)
    tmp = p.with_name(f".{p.stem}.{os.urandom(6).hex()}{p.suffix}")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileNotFoundError:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
        finally:
            os.close(fd)
        os.replace(tmp, p)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_float_image(path: str | Path, img: np.ndarray) -> None:
    """Write a float image as ``.npy`` (float32) or ``.tif``/``.tiff`` (32-bit float)."""
    p = Path(path)
    data = np.ascontiguousarray(img, dtype=np.float32)
    ext = p.suffix.lower()
    if ext == ".npy":
        write_atomic(p, lambda t: np.save(t, data))
    elif ext in (".tif", ".tiff"):
        def _w(t: Path) -> None:
            if not cv2.imwrite(str(t), data):
                raise InputError(f"{p}: could not write 32-bit float TIFF")
        write_atomic(p, _w)
    else:
        raise InputError(f"{p}: output must end in .npy or .tiff, not {ext or '(none)'}")


def write_preview(path: str | Path, image: np.ndarray) -> Path:
    """A float image as an 8-bit grey PNG scaled to its 99.9th percentile, for a person to look
    at beside the data file (written atomically)."""
    p = Path(path)
    if p.suffix.lower() != ".png":
        raise InputError(f"{p}: a preview must be a .png file")
    data = np.nan_to_num(np.asarray(image, dtype=np.float64))
    top = float(np.percentile(data, 99.9)) or 1.0
    img = np.clip(data / top * 255.0, 0, 255).astype(np.uint8)

    def w(t: Path) -> None:
        if not cv2.imwrite(str(t), img):
            raise InputError(f"{p}: could not write PNG")
    write_atomic(p, w)
    return p


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (files only, no display), imported on first use:
    commands that draw nothing do not pay for matplotlib's import."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, **savefig_kw) -> None:
    """Save a matplotlib figure as PNG atomically, then close it (also on failure)."""
    try:
        write_atomic(path, lambda t: fig.savefig(t, format="png", **savefig_kw))
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
