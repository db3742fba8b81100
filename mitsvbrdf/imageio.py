"""Image files <-> float arrays: PNG (8/16-bit, grey, palette, alpha), JPEG, and OpenEXR.

Every array read or written here is a numpy array of shape ``(H, W, C)`` (row 0 at the top of the
image), float32 when read. Channel counts and value ranges:

* PNG / JPEG: integer codes scaled to [0, 1] (8-bit / 255, 16-bit / 65535, 1/2/4-bit greys by
  their own maximum). Values are returned *as stored* (no sRGB decoding). Layouts:
  greyscale -> C = 1; grey + alpha -> C = 4 (RGBA, grey replicated); palette -> C = 3 (RGB), or
  C = 4 when the palette has transparency; RGB -> 3; RGBA -> 4; CMYK / YCbCr JPEGs -> RGB.
  16-bit PNGs are read with pypng (PIL silently truncates 48/64-bit RGB(A) PNGs to 8 bits); the
  bit depth is taken from the file header, not from the extension or from PIL's mode.
  JPEG EXIF orientation is *not* applied (texture maps are read pixel for pixel).
* EXR: linear floats as stored (half, float or uint channels all become float32); see
  :func:`read_image` for which channels are returned in which order, and
  :func:`read_exr_channels` for access to every channel by name. Only the first part of a
  multi-part file is read.

Every failure raises :class:`~mitsvbrdf.errors.ImageFileError` (a ``ValueError``) whose message
starts with the file path and says what is wrong: missing file, unsupported extension, a file that
is not an image, a truncated or corrupt PNG/JPEG/EXR, an array of the wrong shape to write, or an
OS error while writing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .errors import ImageFileError

#: Extensions :func:`read_image` understands (case-insensitive).
READ_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"

_EXR_NAMES = {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


# ---- reading -----------------------------------------------------------------------------------


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file as a float32 ``(H, W, C)`` array, C in {1, 3, 4}.

    Args:
        path: a ``.png``, ``.jpg``/``.jpeg`` or ``.exr`` file.

    Returns:
        PNG/JPEG: values in [0, 1] as stored (see the module docstring for the layouts).
        EXR: the channels of the first part, as stored (linear), chosen and ordered as follows:

        1. if every channel name has the same layer prefix (``"albedo.R"``, ``"albedo.G"``, ...)
           the prefix is ignored;
        2. ``R, G, B, A`` -> RGBA; else ``R, G, B`` -> RGB; else ``Y, A`` -> RGBA with Y
           replicated; else ``Y`` -> 1 channel (names matched case-insensitively; any other
           channels, e.g. ``Z``, are ignored);
        3. otherwise, a file with exactly 1, 3 or 4 channels returns them in alphabetical order of
           their full names (the order EXR stores them in); anything else is an error that points
           to :func:`read_exr_channels`.

    Raises:
        ImageFileError: missing file, unsupported extension, not an image, truncated or corrupt.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READ_SUFFIXES:
        raise ImageFileError(f"{path}: unsupported image type {suffix or '(no extension)'!r}; "
                             f"readable types are {', '.join(READ_SUFFIXES)}")
    _require_file(path)
    if suffix == ".exr":
        return _read_exr(path)
    if suffix == ".png":
        return _read_png(path)
    return _read_pil(path, "JPEG")


def read_exr_channels(path: str | Path) -> dict[str, np.ndarray]:
    """Every channel of an EXR file (its first part) as a float32 ``(H, W)`` array, by full name
    (e.g. ``"R"``, ``"normal.G"``), in alphabetical order of the names.

    Raises:
        ImageFileError: missing file, not an EXR, truncated or corrupt.
    """
    import OpenEXR

    path = Path(path)
    _require_file(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != EXR_MAGIC:
        raise ImageFileError(f"{path}: not an OpenEXR file (bad magic number {magic!r})")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            chans = {name: np.asarray(c.pixels, dtype=np.float32) for name, c in f.channels().items()}
    except Exception as e:  # OpenEXR raises RuntimeError / ValueError variants on corrupt input
        raise ImageFileError(f"{path}: cannot read EXR, the file is truncated or corrupt "
                             f"(OpenEXR: {e})") from e
    if not chans:
        raise ImageFileError(f"{path}: EXR file has no channels")
    shapes = {k: v.shape for k, v in chans.items()}
    if len(set(shapes.values())) != 1:
        raise ImageFileError(f"{path}: EXR channels have different sizes (subsampled?): {shapes}")
    return {k: chans[k] for k in sorted(chans)}


def _require_file(path: Path) -> None:
    if not path.exists():
        raise ImageFileError(f"{path}: file not found")
    if not path.is_file():
        raise ImageFileError(f"{path}: not a regular file")


def _png_header(path: Path) -> tuple[int, int] | None:
    """(bit depth, colour type) from the IHDR chunk, or None when the signature is not PNG's."""
    with open(path, "rb") as f:
        head = f.read(33)
    if head[:8] != PNG_SIGNATURE:
        return None
    if len(head) < 33 or head[12:16] != b"IHDR":
        raise ImageFileError(f"{path}: truncated or corrupt PNG (no complete IHDR header)")
    return head[24], head[25]


def _read_png(path: Path) -> np.ndarray:
    header = _png_header(path)
    if header is None:  # not a PNG by content: maybe a misnamed JPEG, else not an image at all
        return _read_pil(path, "PNG")
    if header[0] == 16:
        return _read_png16(path)
    return _read_pil(path, "PNG")


def _read_png16(path: Path) -> np.ndarray:
    import png

    try:
        with open(path, "rb") as f:
            width, height, rows, info = png.Reader(file=f).asDirect()
            a = np.array([np.asarray(r, dtype=np.uint16) for r in rows], dtype=np.uint16)
    except Exception as e:  # pypng: FormatError, ChunkError, zlib.error, EOF...
        raise ImageFileError(f"{path}: cannot read 16-bit PNG, the file is truncated or corrupt "
                             f"({type(e).__name__}: {e})") from e
    planes = info["planes"]
    if a.shape != (height, width * planes):
        raise ImageFileError(f"{path}: truncated 16-bit PNG ({a.shape[0]} of {height} rows decoded)")
    # asDirect rescales to the sBIT depth when the file has one, so scale by the reported depth.
    out = a.reshape(height, width, planes).astype(np.float32) / float(2 ** info["bitdepth"] - 1)
    if planes == 2:  # grey + alpha -> RGBA
        out = np.concatenate([np.repeat(out[..., :1], 3, -1), out[..., 1:]], -1)
    return out


def _read_pil(path: Path, kind: str) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            return _pil_to_array(im, path)
    except UnidentifiedImageError as e:
        raise ImageFileError(f"{path}: not a {kind} file or any image format PIL recognises") from e
    except (OSError, SyntaxError, ValueError, EOFError, Image.DecompressionBombError) as e:
        raise ImageFileError(f"{path}: cannot read {kind}, the file is truncated or corrupt "
                             f"({type(e).__name__}: {e})") from e


def _pil_to_array(im: Any, path: Path) -> np.ndarray:
    mode = im.mode
    if mode == "1":
        im = im.convert("L")
    elif mode == "P":
        im = im.convert("RGBA" if "transparency" in im.info else "RGB")
    elif mode in ("PA", "LA", "La", "RGBa"):
        im = im.convert("RGBA")
    elif mode in ("CMYK", "YCbCr", "LAB", "HSV"):
        im = im.convert("RGB")
    mode = im.mode
    if mode in ("L", "RGB", "RGBA"):
        a = np.asarray(im, dtype=np.float32) / 255.0
    elif mode.startswith("I;16"):
        a = np.asarray(im, dtype=np.float32) / 65535.0
    else:
        raise ImageFileError(f"{path}: unsupported pixel mode {mode!r}")
    return a[..., None] if a.ndim == 2 else a


def _read_exr(path: Path) -> np.ndarray:
    ch = read_exr_channels(path)
    names = list(ch)
    prefixes = {n.rpartition(".")[0] for n in names}
    short = {n.rpartition(".")[2].upper(): n for n in names} if len(prefixes) == 1 else \
        {n.upper(): n for n in names}
    for want in (("R", "G", "B", "A"), ("R", "G", "B"), ("Y", "A"), ("Y",)):
        if all(w in short for w in want):
            planes = [ch[short[w]] for w in want]
            if want == ("Y", "A"):
                planes = [planes[0]] * 3 + [planes[1]]
            return np.stack(planes, -1)
    if len(names) in (1, 3, 4):
        return np.stack([ch[n] for n in names], -1)
    raise ImageFileError(f"{path}: EXR channels {names} are not RGB(A), Y(A) or 1/3/4 channels; "
                         "read them by name with read_exr_channels()")


# ---- writing -----------------------------------------------------------------------------------


def write_png(path: str | Path, array: np.ndarray, bits: int = 8) -> None:
    """Write an 8- or 16-bit PNG.

    Args:
        path: output file (parent folders are created).
        array: ``(H, W)`` or ``(H, W, C)`` with C = 1 (grey), 2 (grey + alpha), 3 (RGB) or 4
            (RGBA). Floats are clipped to [0, 1] (NaN -> 0) and rounded to the nearest code;
            uint8 / uint16 arrays are taken as codes of their own depth and rescaled if needed.
            Values are written as given (no sRGB encoding).
        bits: 8 or 16.

    Raises:
        ImageFileError: bad ``bits`` or array shape, or the file cannot be written.
    """
    path = Path(path)
    if bits not in (8, 16):
        raise ImageFileError(f"{path}: bits must be 8 or 16, got {bits!r}")
    a = np.asarray(array)
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[-1] in (2, 3, 4))) or a.size == 0:
        raise ImageFileError(f"{path}: write_png needs a non-empty (H, W) or (H, W, 1|2|3|4) array, "
                             f"got shape {a.shape}")
    if a.dtype == np.uint8:
        unit = a.astype(np.float64) / 255.0
    elif a.dtype == np.uint16:
        unit = a.astype(np.float64) / 65535.0
    elif np.issubdtype(a.dtype, np.number) or a.dtype == bool:
        unit = np.clip(np.nan_to_num(a.astype(np.float64), nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    else:
        raise ImageFileError(f"{path}: write_png needs a numeric array, got dtype {a.dtype}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if bits == 8:
            from PIL import Image

            Image.fromarray(np.round(unit * 255).astype(np.uint8)).save(path, format="PNG")
        else:
            import png

            q = np.round(unit * 65535).astype(np.uint16)
            planes = 1 if q.ndim == 2 else q.shape[-1]
            writer = png.Writer(width=q.shape[1], height=q.shape[0], bitdepth=16,
                                greyscale=planes <= 2, alpha=planes in (2, 4))
            with open(path, "wb") as f:
                writer.write_array(f, q.reshape(-1))
    except OSError as e:
        raise ImageFileError(f"{path}: cannot write PNG ({e})") from e


def write_exr(path: str | Path, data: np.ndarray | dict[str, np.ndarray], *, half: bool = False) -> None:
    """Write a scanline EXR (ZIP compression), float32 or, with ``half=True``, float16.

    Args:
        path: output file (parent folders are created).
        data: an ``(H, W)`` / ``(H, W, 1)`` array (written as channel ``Y``), ``(H, W, 3)``
            (``R, G, B``), ``(H, W, 4)`` (``R, G, B, A``), or a dict of named ``(H, W)`` channels
            (e.g. ``{"normal.R": ..., "roughness.Y": ...}``), all the same size.
        half: store 16-bit half floats instead of 32-bit floats (float32 round-trips exactly).

    Raises:
        ImageFileError: bad shapes or channel names, or the file cannot be written.
    """
    import OpenEXR

    path = Path(path)
    if isinstance(data, dict):
        if not data:
            raise ImageFileError(f"{path}: write_exr got no channels")
        chans = {}
        for k, v in data.items():
            if not isinstance(k, str) or not k:
                raise ImageFileError(f"{path}: EXR channel names must be non-empty strings, got {k!r}")
            chans[k] = np.asarray(v)
        shapes = {k: v.shape for k, v in chans.items()}
        if any(len(s) != 2 for s in shapes.values()) or len(set(shapes.values())) != 1:
            raise ImageFileError(f"{path}: EXR channels must all be (H, W) arrays of one size, got {shapes}")
    else:
        a = np.asarray(data)
        if a.ndim == 2:
            a = a[..., None]
        if a.ndim != 3 or a.shape[-1] not in _EXR_NAMES:
            raise ImageFileError(f"{path}: write_exr needs an (H, W) or (H, W, 1|3|4) array, got {a.shape}")
        chans = {n: a[..., i] for i, n in enumerate(_EXR_NAMES[a.shape[-1]])}
    if any(v.size == 0 for v in chans.values()):
        raise ImageFileError(f"{path}: cannot write an empty image")
    dt = np.float16 if half else np.float32
    chans = {k: np.ascontiguousarray(v, dtype=dt) for k, v in chans.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with OpenEXR.File(header, chans) as f:
            f.write(str(path))
    except Exception as e:  # OSError, or OpenEXR's RuntimeError for an unwritable path
        raise ImageFileError(f"{path}: cannot write EXR ({type(e).__name__}: {e})") from e
