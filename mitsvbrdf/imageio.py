"""Image files <-> float arrays: PNG (8/16-bit, grey, palette, alpha), JPEG, and EXR (OpenEXR 3.x).

Arrays are float32 ``(H, W, C)``, C in {1, 3, 4}; integer formats are scaled to [0, 1]. Every
failure raises :class:`~mitsvbrdf.errors.ImageFileError` naming the file and the problem.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import ImageFileError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_bit_depth(path: Path) -> int:
    with open(path, "rb") as f:
        head = f.read(33)
    if len(head) < 33 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise ImageFileError(f"{path}: not a PNG file (bad signature or header)")
    return head[24]


def _read_png(path: Path) -> np.ndarray:
    depth = _png_bit_depth(path)
    if depth == 16:
        import png

        try:
            w, h, rows, info = png.Reader(filename=str(path)).asDirect()
            a = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows])
        except Exception as e:  # pypng raises its own FormatError/ChunkError
            raise ImageFileError(f"{path}: corrupt or truncated 16-bit PNG ({e})") from e
        planes = info["planes"]
        return (a.reshape(h, w, planes).astype(np.float32) / 65535.0)
    return _read_pil(path)


def _read_pil(path: Path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("P", "PA", "CMYK", "YCbCr", "LAB", "HSV", "1"):
                im = im.convert("RGBA" if "transparency" in im.info or im.mode == "PA" else "RGB")
            if im.mode == "LA":
                im = im.convert("RGBA")
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float32) / 65535.0
            elif im.mode == "F":
                a = np.asarray(im, dtype=np.float32)
            else:
                a = np.asarray(im, dtype=np.float32) / 255.0
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise ImageFileError(f"{path}: cannot read image ({e})") from e
    return a[..., None] if a.ndim == 2 else a


def read_exr_channels(path: str | Path) -> dict[str, np.ndarray]:
    """All channels of an EXR file as float32 (H, W) arrays, by channel name."""
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise ImageFileError(f"{path}: file not found")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            chans = f.channels()
            return {name: np.asarray(c.pixels, dtype=np.float32) for name, c in chans.items()}
    except Exception as e:  # OpenEXR raises RuntimeError/ValueError variants on corrupt input
        raise ImageFileError(f"{path}: cannot read EXR ({e})") from e


def _read_exr(path: Path) -> np.ndarray:
    ch = read_exr_channels(path)
    for names in (("R", "G", "B", "A"), ("R", "G", "B"), ("Y",)):
        if all(n in ch for n in names):
            return np.stack([ch[n] for n in names], -1)
    names = sorted(ch)
    if len(names) in (1, 3, 4):
        return np.stack([ch[n] for n in names], -1)
    raise ImageFileError(f"{path}: EXR channels {names} are not RGB(A)/Y; read them with read_exr_channels")


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as float32 (H, W, C); PNG/JPEG values in [0, 1], EXR as stored (linear)."""
    path = Path(path)
    if not path.is_file():
        raise ImageFileError(f"{path}: file not found")
    suffix = path.suffix.lower()
    if suffix == ".exr":
        return _read_exr(path)
    if suffix == ".png":
        return _read_png(path)
    if suffix in (".jpg", ".jpeg", ".tif", ".tiff", ".bmp"):
        return _read_pil(path)
    raise ImageFileError(f"{path}: unsupported image type {suffix!r} (use .png, .exr, .jpg)")


def write_png(path: str | Path, array: np.ndarray, bits: int = 8) -> None:
    """Write (H, W), (H, W, 1|3|4) values in [0, 1] (clipped) or uint8 as an 8- or 16-bit PNG."""
    from PIL import Image

    a = np.asarray(array)
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if a.dtype == np.uint8:
        a = a.astype(np.float32) / 255.0
    a = np.clip(np.nan_to_num(a.astype(np.float64)), 0.0, 1.0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if bits == 8:
        Image.fromarray(np.round(a * 255).astype(np.uint8)).save(path)
    elif bits == 16:
        import png

        q = np.round(a * 65535).astype(np.uint16)
        planes = 1 if q.ndim == 2 else q.shape[-1]
        png.Writer(width=q.shape[1], height=q.shape[0], bitdepth=16, greyscale=planes == 1,
                   alpha=planes in (2, 4)).write(open(path, "wb"), q.reshape(q.shape[0], -1).tolist())
    else:
        raise ValueError(f"bits must be 8 or 16, got {bits}")


def write_exr(path: str | Path, data: np.ndarray | dict[str, np.ndarray], half: bool = False) -> None:
    """Write an (H, W, 1|3|4) array (as Y / RGB / RGBA) or a dict of named (H, W) channels."""
    import OpenEXR

    if isinstance(data, dict):
        chans = data
    else:
        a = np.asarray(data)
        if a.ndim == 2:
            a = a[..., None]
        names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(a.shape[-1])
        if names is None:
            raise ValueError(f"write_exr needs 1, 3 or 4 channels, got {a.shape}")
        chans = {n: a[..., i] for i, n in enumerate(names)}
    dt = np.float16 if half else np.float32
    chans = {k: np.ascontiguousarray(v, dtype=dt) for k, v in chans.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, chans) as f:
        f.write(str(path))


def tonemap_preview(array: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """Linear radiance -> uint8 sRGB preview; ``exposure`` None maps the 99th percentile to 1."""
    a = np.nan_to_num(np.asarray(array, dtype=np.float64))
    if exposure is None:
        p = np.percentile(a, 99)
        exposure = 1.0 / p if p > 0 else 1.0
    x = np.clip(a * exposure, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(srgb * 255).astype(np.uint8)
