"""The SVBRDF container: four maps in memory, validated, and their file formats.

Maps are float32 torch tensors, always batched:

    normal    (B, 3, H, W)  unit tangent-space vectors (x right, y up, z out of the surface)
    diffuse   (B, 3, H, W)  kd in [0, 1], linear
    roughness (B, 1, H, W)  r in [0, 1] (GGX alpha = r^2)
    specular  (B, 3, H, W)  ks in [0, 1], linear

Row 0 is the top of the sample (y = +size/2), column 0 its left edge. The *encoded* form, used by
files and by RMSE metrics, stores the normal as (n + 1) / 2 and everything else as is
(the Deschaintre et al. 2018 convention: stored albedo values are used as-is; ``srgb_albedo=True``
decodes sRGB-stored albedos instead).

File formats (:meth:`SVBRDF.load` / :meth:`SVBRDF.save`):

* strip PNG of 4 square tiles ``[normal | diffuse | roughness | specular]``, or the 5-tile dataset
  strip ``[render | normal | diffuse | roughness | specular]`` (the render tile is kept, as stored,
  in ``.render``);
* a folder with ``normal``, ``diffuse``, ``roughness`` and ``specular`` as ``.png`` or ``.exr``;
* one ``.exr`` with layered channels ``normal.R/G/B``, ``diffuse.R/G/B``, ``roughness.Y``,
  ``specular.R/G/B`` (float32, the normal stored as the raw unit vector, not encoded).

Normals read from files are renormalised (8-bit quantisation, and real datasets hold texels far
from unit length, some with z <= 0: those are clamped to z >= 1e-3 first). When more than 1% of
texels are off unit length by > 0.05, or any has z <= 0, a warning names the file and the counts;
``strict=True`` makes that an error.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .errors import ImageFileError, MaterialError
from .imageio import read_exr_channels, read_image, write_exr, write_png

MAP_NAMES = ("normal", "diffuse", "roughness", "specular")
_CHANNELS = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}
_FILE_SUFFIXES = (".png", ".exr")


def encode_maps(normal: Tensor, diffuse: Tensor, roughness: Tensor, specular: Tensor) -> Tensor:
    """Maps -> encoded (B, 10, H, W) (or (10, H, W) without batch): normal as (n + 1) / 2."""
    return torch.cat([(normal + 1) / 2, diffuse, roughness, specular], dim=-3)


def decode_maps(t: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Encoded (..., 10, H, W) -> (normal renormalised, diffuse, roughness, specular)."""
    if t.shape[-3] != 10:
        raise MaterialError(f"encoded maps need 10 channels, got {t.shape[-3]}")
    n = t[..., 0:3, :, :] * 2 - 1
    n = n / torch.linalg.vector_norm(n, dim=-3, keepdim=True).clamp_min(1e-12)
    return n, t[..., 3:6, :, :], t[..., 6:7, :, :], t[..., 7:10, :, :]


def _srgb_to_linear(x: Tensor) -> Tensor:
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


@dataclass(eq=False)
class SVBRDF:
    """Four maps of B materials (see the module docstring); validated on construction."""

    normal: Tensor
    diffuse: Tensor
    roughness: Tensor
    specular: Tensor
    render: Tensor | None = None
    name: str | None = None
    validate_maps: bool = True

    def __post_init__(self):
        for k in MAP_NAMES:
            t = getattr(self, k)
            if not isinstance(t, Tensor):
                t = torch.as_tensor(np.asarray(t), dtype=torch.float32)
            if t.ndim == 3:
                t = t.unsqueeze(0)
            setattr(self, k, t)
        if self.roughness.ndim == 4 and self.roughness.shape[1] == 3:
            r = self.roughness.detach()
            if (r - r[:, :1]).abs().max() > 1 / 255 + 1e-6:
                raise MaterialError("roughness given with 3 channels that differ; it is a 1-channel map")
            self.roughness = self.roughness[:, :1]
        if self.render is not None and self.render.ndim == 3:
            self.render = self.render.unsqueeze(0)
        if self.validate_maps:
            self.validate()

    # ---- validation ---------------------------------------------------------------------------

    def validate(self) -> None:
        """Raise MaterialError naming the map and the problem (shape, NaN, range, unit normals)."""
        ref = None
        for k in MAP_NAMES:
            t = getattr(self, k)
            if t.ndim != 4 or t.shape[1] != _CHANNELS[k]:
                raise MaterialError(f"{k} map must be (B, {_CHANNELS[k]}, H, W), got {tuple(t.shape)}")
            if ref is None:
                ref = (t.shape[0], *t.shape[2:])
            elif (t.shape[0], *t.shape[2:]) != ref:
                raise MaterialError(f"{k} map is {tuple(t.shape)}, but the normal map is "
                                    f"(B={ref[0]}, H={ref[1]}, W={ref[2]}): sizes must match")
            d = t.detach()
            bad = ~torch.isfinite(d)
            if bad.any():
                raise MaterialError(f"{k} map has {int(bad.sum())} NaN/Inf values")
            if k != "normal":
                lo, hi = float(d.min()), float(d.max())
                if lo < -1e-4 or hi > 1 + 1e-4:
                    raise MaterialError(f"{k} map must lie in [0, 1], got range [{lo:.4g}, {hi:.4g}]")
        n = self.normal.detach()
        length = torch.linalg.vector_norm(n, dim=1)
        off = (length - 1).abs()
        if off.max() > 1e-3:
            raise MaterialError(f"normal map is not unit length at {int((off > 1e-3).sum())} texels "
                                f"(worst |n| = {float(length.flatten()[off.argmax()]):.4g}); normalise it")
        if (n[:, 2] < 0).any():
            raise MaterialError(f"normal map points into the surface (z < 0) at {int((n[:, 2] < 0).sum())} texels")

    # ---- basic properties ---------------------------------------------------------------------

    @property
    def batch_size(self) -> int:
        return self.normal.shape[0]

    def __len__(self) -> int:
        return self.batch_size

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.normal.shape[-2:])

    @property
    def device(self) -> torch.device:
        return self.normal.device

    @property
    def dtype(self) -> torch.dtype:
        return self.normal.dtype

    def maps(self) -> dict[str, Tensor]:
        return {k: getattr(self, k) for k in MAP_NAMES}

    def _with(self, fn) -> "SVBRDF":
        return SVBRDF(**{k: fn(v) for k, v in self.maps().items()},
                      render=None if self.render is None else fn(self.render), name=self.name,
                      validate_maps=False)

    def to(self, *args, **kwargs) -> "SVBRDF":
        return self._with(lambda t: t.to(*args, **kwargs))

    def detach(self) -> "SVBRDF":
        return self._with(lambda t: t.detach())

    def requires_grad_(self, flag: bool = True) -> "SVBRDF":
        for t in self.maps().values():
            t.requires_grad_(flag)
        return self

    def __getitem__(self, i) -> "SVBRDF":
        sel = (lambda t: t[i:i + 1]) if isinstance(i, int) else (lambda t: t[i])
        return self._with(sel)

    @staticmethod
    def cat(items: list["SVBRDF"]) -> "SVBRDF":
        """Concatenate materials of the same resolution along the batch."""
        renders = [s.render for s in items]
        return SVBRDF(**{k: torch.cat([getattr(s, k) for s in items]) for k in MAP_NAMES},
                      render=torch.cat(renders) if all(r is not None for r in renders) else None)

    def encoded(self) -> Tensor:
        """(B, 10, H, W) encoded maps."""
        return encode_maps(self.normal, self.diffuse, self.roughness, self.specular)

    @classmethod
    def from_encoded(cls, t: Tensor, **kwargs) -> "SVBRDF":
        return cls(*decode_maps(t), **kwargs)

    @classmethod
    def constant(cls, normal=(0.0, 0.0, 1.0), diffuse=0.5, roughness=0.5, specular=0.04,
                 size: int | tuple[int, int] = 64, batch: int = 1) -> "SVBRDF":
        """A homogeneous material; albedos as scalars or RGB triples, normal as a 3-vector."""
        h, w = (size, size) if isinstance(size, int) else size

        def fill(v, c):
            v = torch.as_tensor(v, dtype=torch.float32).reshape(-1)
            v = v.expand(c) if v.numel() == 1 else v
            if v.numel() != c:
                raise MaterialError(f"expected 1 or {c} values, got {v.numel()}")
            return v.view(1, c, 1, 1).expand(batch, c, h, w).clone()

        n = torch.as_tensor(normal, dtype=torch.float32)
        return cls(normal=fill(n / n.norm(), 3), diffuse=fill(diffuse, 3),
                   roughness=fill(roughness, 1), specular=fill(specular, 3))

    # ---- files --------------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path, *, strict: bool = False, srgb_albedo: bool = False) -> "SVBRDF":
        """Load a strip PNG, a folder of per-map files, or a layered EXR (see the module docstring)."""
        path = Path(path)
        if path.is_dir():
            maps, render = _load_folder(path), None
        elif not path.exists():
            raise ImageFileError(f"{path}: no such file or folder")
        elif path.suffix.lower() == ".exr":
            maps, render = _load_exr(path), None
        else:
            maps, render = _load_strip(path)
        if path.suffix.lower() != ".exr":
            maps["normal"] = _decode_file_normals(maps["normal"], path, strict)
        if maps["roughness"].shape[-1] == 3:
            r = maps["roughness"]
            if np.abs(r - r[..., :1]).max() > 1.5 / 255:
                msg = f"{path}: roughness channels differ (max {np.abs(r - r[..., :1]).max():.3g}); using red"
                if strict:
                    raise MaterialError(msg)
                warnings.warn(msg, stacklevel=2)
            maps["roughness"] = r[..., :1]
        for k in ("diffuse", "specular"):
            if maps[k].shape[-1] == 4:
                maps[k] = maps[k][..., :3]
            if maps[k].shape[-1] == 1:
                maps[k] = np.repeat(maps[k], 3, -1)
        tensors = {k: torch.from_numpy(np.ascontiguousarray(v)).permute(2, 0, 1).float()
                   for k, v in maps.items()}
        if srgb_albedo:
            for k in ("diffuse", "specular"):
                tensors[k] = _srgb_to_linear(tensors[k])
        for k, t in tensors.items():
            if t.shape[0] != _CHANNELS[k]:
                raise MaterialError(f"{path}: {k} map has {t.shape[0]} channels, expected {_CHANNELS[k]}")
        try:
            return cls(**tensors, render=None if render is None else torch.from_numpy(render).permute(2, 0, 1).float(),
                       name=path.stem)
        except MaterialError as e:
            raise MaterialError(f"{path}: {e}") from None

    def save(self, path: str | Path, *, include_render: bool = True) -> None:
        """``.png``: strip (with the render tile when present); ``.exr``: layered EXR;
        no suffix: folder of four PNGs. One material (B == 1) per path."""
        if self.batch_size != 1:
            raise MaterialError(f"save writes one material, this SVBRDF holds {self.batch_size}; "
                                "save svbrdf[i] for each i")
        path = Path(path)
        maps = {k: v[0].detach().cpu().permute(1, 2, 0).numpy() for k, v in self.maps().items()}
        if path.suffix.lower() == ".exr":
            chans = {f"normal.{c}": maps["normal"][..., i] for i, c in enumerate("RGB")}
            chans.update({f"diffuse.{c}": maps["diffuse"][..., i] for i, c in enumerate("RGB")})
            chans["roughness.Y"] = maps["roughness"][..., 0]
            chans.update({f"specular.{c}": maps["specular"][..., i] for i, c in enumerate("RGB")})
            write_exr(path, chans)
            return
        enc = dict(maps, normal=(maps["normal"] + 1) / 2, roughness=np.repeat(maps["roughness"], 3, -1))
        if path.suffix.lower() == ".png":
            tiles = [enc[k] for k in MAP_NAMES]
            if include_render and self.render is not None:
                tiles.insert(0, self.render[0].detach().cpu().permute(1, 2, 0).numpy()[..., :3])
            write_png(path, np.concatenate(tiles, axis=1))
        elif path.suffix == "":
            path.mkdir(parents=True, exist_ok=True)
            for k in MAP_NAMES:
                write_png(path / f"{k}.png", enc[k])
        else:
            raise ImageFileError(f"{path}: save as .png (strip), .exr, or a folder (no suffix)")


def _load_strip(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    img = read_image(path)
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, -1)
    img = img[..., :3]
    h, w = img.shape[:2]
    if w == 4 * h:
        tiles, render = [img[:, i * h:(i + 1) * h] for i in range(4)], None
    elif w == 5 * h:
        tiles = [img[:, i * h:(i + 1) * h] for i in range(1, 5)]
        render = img[:, :h]
    else:
        raise MaterialError(f"{path}: a strip must be 4 or 5 square tiles wide (width {4 * h} or "
                            f"{5 * h} for height {h}), got {w}x{h}")
    return dict(zip(MAP_NAMES, tiles)), render


def _load_folder(path: Path) -> dict[str, np.ndarray]:
    maps = {}
    for k in MAP_NAMES:
        found = [path / f"{k}{s}" for s in _FILE_SUFFIXES if (path / f"{k}{s}").is_file()]
        if not found:
            raise ImageFileError(f"{path}: missing the {k} map ({k}.png or {k}.exr)")
        maps[k] = read_image(found[0])
        if found[0].suffix == ".exr" and k == "normal":
            maps[k] = (maps[k] + 1) / 2  # folder EXRs store raw vectors; decoded uniformly below
    sizes = {k: v.shape[:2] for k, v in maps.items()}
    if len(set(sizes.values())) != 1:
        raise MaterialError(f"{path}: maps differ in size: {sizes}")
    return maps


def _load_exr(path: Path) -> dict[str, np.ndarray]:
    ch = read_exr_channels(path)
    want = {"normal": "RGB", "diffuse": "RGB", "specular": "RGB"}
    maps = {}
    for k, cs in want.items():
        names = [f"{k}.{c}" for c in cs]
        if not all(n in ch for n in names):
            raise MaterialError(f"{path}: EXR lacks channels {names} (has {sorted(ch)})")
        maps[k] = np.stack([ch[n] for n in names], -1)
    if "roughness.Y" not in ch:
        raise MaterialError(f"{path}: EXR lacks channel 'roughness.Y'")
    maps["roughness"] = ch["roughness.Y"][..., None]
    n = maps["normal"]
    maps["normal"] = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return maps


def _decode_file_normals(enc: np.ndarray, path: Path, strict: bool) -> np.ndarray:
    n = enc[..., :3].astype(np.float64) * 2 - 1
    length = np.linalg.norm(n, axis=-1)
    off = np.abs(length - 1) > 0.05
    below = n[..., 2] <= 0
    if off.mean() > 0.01 or below.any():
        msg = (f"{path}: normal map has {off.sum()} texels off unit length by > 0.05 and "
               f"{below.sum()} with z <= 0 (of {off.size}); renormalised")
        if strict:
            raise MaterialError(msg.replace("; renormalised", ""))
        warnings.warn(msg, stacklevel=3)
    n[..., 2] = np.maximum(n[..., 2], 1e-3)
    return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
