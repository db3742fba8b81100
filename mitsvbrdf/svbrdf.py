"""The SVBRDF container: four maps in memory, validated, and their file formats.

Maps (docs/conventions.md) are floating-point torch tensors (float32 unless converted with
:meth:`SVBRDF.to`), always batched, all linear:

    normal    (B, 3, H, W)  unit tangent-space vectors: x right, y up, z out of the surface (z >= 0)
    diffuse   (B, 3, H, W)  diffuse albedo kd in [0, 1]
    roughness (B, 1, H, W)  roughness r in [0, 1] (the BRDF uses GGX alpha = r^2)
    specular  (B, 3, H, W)  specular albedo ks in [0, 1]

Row 0 is the top of the sample (y = +size/2), column 0 its left edge: the standard tangent-space
normal map convention, so a normal tilted towards the top of the image has n_y > 0.

The *encoded* form (files, RMSE metrics, networks) is ``(B, 10, H, W)``: channels 0-2 the normal as
(n + 1) / 2, 3-5 diffuse, 6 roughness, 7-9 specular, the last three as stored values in [0, 1].

Albedo encoding, the one convention of loader, generator, renderers and metrics: **stored albedo
values are the linear kd / ks.** :meth:`SVBRDF.load` keeps them as stored (8-bit code / 255, no
decoding), the renderers and :mod:`mitsvbrdf.relight` use them as linear albedos, the procedural
generator (:mod:`mitsvbrdf.data.procedural`) draws them in that same sense, and the metrics
(:func:`mitsvbrdf.metrics.map_rmse` on :meth:`SVBRDF.encoded`) compare them as stored, as in the
paper. This is the Deschaintre et al. 2018 renderer's reading (it renders the stored values), and
the one under which the dataset's dielectric specular, stored as 11/255 = 0.043, is the physical
F0 ~ 0.04 (sRGB-decoded it would be 0.003). The datasets' own flash renders do not overturn it:
fitting them under linear, sRGB-decoded and kd-only-decoded albedos
(``benchmarks/albedo_encoding.py``, docs/benchmarks/albedo_encoding.md) the 4 sample materials
split (two fit sRGB-decoded albedos better, one linear, one neither) and kd-only decoding fits
worst. ``SVBRDF.load(..., srgb_albedo=True)`` is for a dataset known to store sRGB-encoded albedos:
it decodes them on load, so that set's maps, encoded form and metrics are then on linear values,
not its stored ones. :mod:`mitsvbrdf.data.encoding` checks a set of 5-tile strips against its
render tiles.

File formats (:meth:`SVBRDF.load` / :meth:`SVBRDF.save`):

* **strip PNG** of square tiles side by side: ``[normal | diffuse | roughness | specular]``
  (width = 4 x height), or the 5-tile dataset strip ``[render | normal | diffuse | roughness |
  specular]`` (width = 5 x height). Tiles hold encoded values (8 or 16 bit); the roughness tile is
  grey (three equal channels). The render tile goes to :attr:`SVBRDF.render` with its values as
  stored (sRGB-encoded 8-bit photographs/renders in the dataset, scaled to [0, 1], not decoded).
  A JPEG strip is read the same way.
* **folder** holding exactly ``normal``, ``diffuse``, ``roughness`` and ``specular``, each as
  ``.png`` (encoded values, like the strip tiles) or ``.exr`` (float values; the normal as the raw
  unit vector, not encoded), all the same size. Other names (``basecolor``, ``albedo``, ...) are
  not recognised. Greyscale diffuse/specular files are replicated to RGB, alpha is dropped.
* **layered EXR**: one ``.exr`` with float channels ``normal.R/G/B`` (raw unit vector, not
  encoded), ``diffuse.R/G/B``, ``roughness.Y``, ``specular.R/G/B`` and, if present,
  ``render.R/G/B``; float32, so it round-trips exactly.

Normals read from files are cleaned: 8-bit quantisation leaves them off unit length, and real
datasets hold texels far from it, some with z <= 0. Every file normal has z clamped to >= 1e-3 and
is renormalised (texels already unit length to 1e-6 are kept bit for bit). When more than 1% of
texels are off unit length by > 0.05, or any has z <= 0, one ``UserWarning`` names the file and the
counts; ``strict=True`` makes that a :class:`MaterialError`. A roughness file with three unequal
channels (by more than 1/255) is read from its first channel with a warning (``strict``: error).

Errors: a file that is missing, unreadable or of an unsupported type raises
:class:`~mitsvbrdf.errors.ImageFileError`; file content that does not form a valid SVBRDF (strip
width, missing EXR layers, sizes, ranges, NaN) raises :class:`~mitsvbrdf.errors.MaterialError`.
Both name the file.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import InitVar, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .errors import ImageFileError, MaterialError
from .imageio import read_exr_channels, read_image, write_exr, write_png

#: The four maps, in their canonical (and encoded / strip) order.
MAP_NAMES = ("normal", "diffuse", "roughness", "specular")
#: Channels of each map in memory.
MAP_CHANNELS = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}
#: Channels of the encoded form.
ENCODED_CHANNELS = 10
#: Each map's channels in the encoded form (the maps in :data:`MAP_NAMES` order).
ENCODED_SLICES = {k: slice(sum(MAP_CHANNELS[m] for m in MAP_NAMES[:i]), sum(MAP_CHANNELS[m] for m in MAP_NAMES[:i + 1]))
                  for i, k in enumerate(MAP_NAMES)}

RANGE_TOL = 1e-4            # maps may exceed [0, 1] by this much (float round-off)
NORMAL_TOL = 1e-3           # in-memory normals: | |n| - 1 | allowed
ROUGHNESS_CHANNEL_TOL = 1 / 255  # three roughness channels may differ by this much (quantisation)
FILE_NORMAL_TOL = 0.05      # file normals off unit length by more than this count as "bad" ...
FILE_NORMAL_FRACTION = 0.01  # ... and more than this fraction of bad texels warns
NORMAL_MIN_Z = 1e-3         # file normals get z clamped to at least this before renormalising

_EXR_LAYERS = {"normal": "RGB", "diffuse": "RGB", "roughness": "Y", "specular": "RGB"}


# ---- encoded form ------------------------------------------------------------------------------


def encode_maps(normal: Tensor, diffuse: Tensor, roughness: Tensor, specular: Tensor) -> Tensor:
    """Concatenate the maps into the encoded form, the normal as (n + 1) / 2.

    Args:
        normal, diffuse, roughness, specular: ``(B, C, H, W)`` maps (C = 3, 3, 1, 3), or all
            unbatched ``(C, H, W)``.

    Returns:
        ``(B, 10, H, W)`` (or ``(10, H, W)`` for unbatched input); differentiable.
    """
    maps = {"normal": normal, "diffuse": diffuse, "roughness": roughness, "specular": specular}
    ndims = {k: v.ndim for k, v in maps.items()}
    if len(set(ndims.values())) != 1 or normal.ndim not in (3, 4):
        raise MaterialError(f"encode_maps needs four (B, C, H, W) or four (C, H, W) maps, got shapes "
                            f"{ {k: tuple(v.shape) for k, v in maps.items()} }")
    for k, v in maps.items():
        if v.shape[-3] != MAP_CHANNELS[k]:
            raise MaterialError(f"encode_maps: {k} map has {v.shape[-3]} channels, expected {MAP_CHANNELS[k]}")
    return torch.cat([(normal + 1) / 2, diffuse, roughness, specular], dim=-3)


def decode_maps(t: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Inverse of :func:`encode_maps`.

    Args:
        t: ``(B, 10, H, W)`` or ``(10, H, W)`` encoded maps.

    Returns:
        ``(normal, diffuse, roughness, specular)`` with the batch dimension iff ``t`` has it; the
        normal is decoded as 2 t - 1 and renormalised to unit length (a zero vector stays zero).
        Differentiable.
    """
    if not isinstance(t, Tensor) or t.ndim not in (3, 4) or t.shape[-3] != ENCODED_CHANNELS:
        shape = tuple(t.shape) if isinstance(t, Tensor) else type(t).__name__
        raise MaterialError(f"encoded maps must be (B, 10, H, W) or (10, H, W), got {shape}")
    n = t[..., 0:3, :, :] * 2 - 1
    n = n / torch.linalg.vector_norm(n, dim=-3, keepdim=True).clamp_min(1e-12)
    return n, t[..., 3:6, :, :], t[..., 6:7, :, :], t[..., 7:10, :, :]


def srgb_to_linear(x: Tensor) -> Tensor:
    """The sRGB decoding curve (IEC 61966-2-1), elementwise on values in [0, 1]."""
    return torch.where(x <= 0.04045, x / 12.92, ((x.clamp_min(0) + 0.055) / 1.055) ** 2.4)


def resample_texels(t: Tensor, size: tuple[int, int]) -> Tensor:
    """``(..., C, H, W)`` -> ``(..., C, h, w)``: area averages when no axis grows (each new texel
    the mean over the old ones it covers; for linear radiance, what a coarser sensor records),
    bilinear interpolation otherwise. Returns ``t`` itself when the size is already that."""
    h, w = size
    if tuple(t.shape[-2:]) == (h, w):
        return t
    lead = t.shape[:-3]
    x = t.reshape(-1, *t.shape[-3:])
    if h <= t.shape[-2] and w <= t.shape[-1]:
        x = torch.nn.functional.interpolate(x, size=(h, w), mode="area")
    else:
        x = torch.nn.functional.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)
    return x.reshape(*lead, *x.shape[-3:])


def texel_phases(fine: tuple[int, int], coarse: tuple[int, int]) -> list[tuple[float, float]]:
    """The points (y, x) within a texel of the ``coarse`` grid (h, w), as fractions of its extent,
    that land on the texels of the ``fine`` grid (H, W) it covers: ((i + 1/2) / k_y, (j + 1/2) / k_x)
    for k = ceil(H / h) x ceil(W / w) (an integer ratio: each of a block's k_y k_x texels exactly)."""
    ky, kx = (-(-int(f) // int(c)) for f, c in zip(fine, coarse))
    return [((i + 0.5) / ky, (j + 0.5) / kx) for i in range(ky) for j in range(kx)]


def sample_within_texels(t: Tensor, size: tuple[int, int], at: tuple[float, float] = (0.5, 0.5)) -> Tensor:
    """``(..., C, H, W)`` -> ``(..., C, h, w)``, h <= H and w <= W: ``t`` at one point of each texel
    of the coarser grid, ``at`` = (y, x) its position within the texel as fractions of its extent,
    bilinear between the four texels nearest it (the border texels extended). At the centre of a
    grid 4x coarser: the mean of each block's central 2 x 2 texels; at a point of
    :func:`texel_phases`: one texel of each block. Where :func:`resample_texels` gives a coarse
    texel of a capture the radiance mixed over its whole area, this keeps the radiance of a patch
    of the fine pitch at one place in it."""
    h, w = size
    if h > t.shape[-2] or w > t.shape[-1]:
        raise ValueError(f"sample_within_texels samples a coarser grid; got {tuple(t.shape[-2:])} -> {(h, w)}")
    lead = t.shape[:-3]
    x = t.reshape(-1, *t.shape[-3:])
    # grid_sample's coordinates (align_corners=False): -1 and 1 are the outer edges of the grid
    ys = (torch.arange(h, dtype=x.dtype, device=x.device) + at[0]) * (2.0 / h) - 1.0
    xs = (torch.arange(w, dtype=x.dtype, device=x.device) + at[1]) * (2.0 / w) - 1.0
    grid = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1).expand(x.shape[0], h, w, 2)
    x = torch.nn.functional.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return x.reshape(*lead, *x.shape[-3:])


# ---- the container -----------------------------------------------------------------------------


@dataclass(eq=False, repr=False)
class SVBRDF:
    """B materials' maps (see the module docstring for shapes, ranges and conventions).

    Construct with batched ``(B, C, H, W)`` or unbatched ``(C, H, W)`` maps (a batch dimension is
    added); arrays are converted to float32 tensors, floating tensors are kept as they are (so
    gradients flow to them). A roughness given with 3 channels is reduced to its first channel
    (error if they differ by more than 1/255).

    Construction validates the maps (:meth:`validate`); pass ``check=False`` to skip that for
    maps known to be valid (e.g. in an optimisation loop) and call :meth:`validate` when needed.

    Attributes:
        normal, diffuse, roughness, specular: the maps.
        render: optional ``(B, 3, H, W)`` image that came with the material (the leading render tile
            of a 5-tile dataset strip), values as stored; ``None`` if absent.
        name: optional label (the file stem when loaded).
    """

    normal: Tensor
    diffuse: Tensor
    roughness: Tensor
    specular: Tensor
    render: Tensor | None = None
    name: str | None = None
    check: InitVar[bool] = True

    def __post_init__(self, check: bool) -> None:
        for k in MAP_NAMES:
            setattr(self, k, _as_batched(getattr(self, k), f"{k} map"))
        r = self.roughness
        if r.ndim == 4 and r.shape[1] == 3:
            spread = float((r.detach() - r.detach()[:, :1]).abs().amax()) if r.numel() else 0.0
            if spread > ROUGHNESS_CHANNEL_TOL + 1e-6:
                raise MaterialError(f"roughness map given with 3 channels that differ by up to {spread:.4g} "
                                    f"(> 1/255); roughness is one channel: pass (B, 1, H, W)")
            self.roughness = r[:, :1]
        if self.render is not None:
            self.render = _as_batched(self.render, "render tile")
        if check:
            self.validate()

    # ---- validation -------------------------------------------------------------------------

    def validate(self) -> None:
        """Check shapes, dtypes, finiteness, ranges and unit normals; return None or raise.

        Raises:
            MaterialError: naming the map and the problem: wrong ndim / channel count, batch size or
                resolution differing from the normal map's, differing dtype or device, NaN/Inf
                (how many texels), values outside [0, 1] by more than 1e-4 (min and max), normals
                off unit length by more than 1e-3 (how many texels and the worst length), normals
                with z < 0 (how many). Checks run on detached tensors and never touch autograd.
        """
        ref = self.normal
        for k in MAP_NAMES:
            t = getattr(self, k)
            c = MAP_CHANNELS[k]
            if not isinstance(t, Tensor):
                raise MaterialError(f"{k} map must be a torch tensor, got {type(t).__name__}")
            if t.ndim != 4 or t.shape[1] != c:
                raise MaterialError(f"{k} map must be (B, {c}, H, W) (or ({c}, H, W)), got shape {tuple(t.shape)}")
            if not t.is_floating_point():
                raise MaterialError(f"{k} map must be floating point, got {t.dtype}")
            if t.numel() == 0:
                raise MaterialError(f"{k} map is empty, shape {tuple(t.shape)}")
            if (t.shape[0], *t.shape[2:]) != (ref.shape[0], *ref.shape[2:]):
                raise MaterialError(f"{k} map has shape {tuple(t.shape)} but the normal map has "
                                    f"{tuple(ref.shape)}: sizes must match (batch size B and resolution H, W)")
            if t.dtype != ref.dtype or t.device != ref.device:
                raise MaterialError(f"{k} map is {t.dtype} on {t.device} but the normal map is "
                                    f"{ref.dtype} on {ref.device}: all maps must share dtype and device")
            d = t.detach()
            bad = ~torch.isfinite(d).all(dim=1)
            if bad.any():
                raise MaterialError(f"{k} map has NaN or Inf at {int(bad.sum())} of {bad.numel()} texels")
            if k != "normal":
                lo, hi = float(d.amin()), float(d.amax())
                if lo < -RANGE_TOL or hi > 1 + RANGE_TOL:
                    outside = int(((d < -RANGE_TOL) | (d > 1 + RANGE_TOL)).sum())
                    raise MaterialError(f"{k} map must lie in [0, 1], got min {lo:.6g}, max {hi:.6g} "
                                        f"({outside} values outside)")
        n = self.normal.detach()
        length = torch.linalg.vector_norm(n, dim=1)
        off = (length - 1).abs()
        nbad = int((off > NORMAL_TOL).sum())
        if nbad:
            worst = int(off.argmax())
            b, rem = divmod(worst, off.shape[1] * off.shape[2])
            i, j = divmod(rem, off.shape[2])
            raise MaterialError(f"normal map is not unit length at {nbad} of {off.numel()} texels (worst |n| = "
                                f"{float(length.flatten()[worst]):.6g} at batch {b}, row {i}, column {j}); "
                                "normalise it, e.g. n / n.norm(dim=1, keepdim=True)")
        below = n[:, 2] < 0
        if below.any():
            raise MaterialError(f"normal map points into the surface (z < 0) at {int(below.sum())} of "
                                f"{below.numel()} texels (min z = {float(n[:, 2].amin()):.4g})")
        if self.render is not None:
            r = self.render
            if not isinstance(r, Tensor) or r.ndim != 4 or tuple(r.shape) != (ref.shape[0], 3, *ref.shape[2:]):
                shape = tuple(r.shape) if isinstance(r, Tensor) else type(r).__name__
                raise MaterialError(f"render tile must be (B, 3, H, W) = {(ref.shape[0], 3, *ref.shape[2:])} "
                                    f"like the maps, got {shape}")
            if not torch.isfinite(r.detach()).all():
                raise MaterialError("render tile has NaN or Inf values")
        if self.name is not None and not isinstance(self.name, str):
            raise MaterialError(f"name must be a string or None, got {type(self.name).__name__}")

    # ---- basic properties -------------------------------------------------------------------

    @property
    def batch_size(self) -> int:
        """Number of materials B."""
        return self.normal.shape[0]

    def __len__(self) -> int:
        return self.batch_size

    @property
    def resolution(self) -> tuple[int, int]:
        """``(H, W)`` in texels."""
        return int(self.normal.shape[-2]), int(self.normal.shape[-1])

    @property
    def device(self) -> torch.device:
        return self.normal.device

    @property
    def dtype(self) -> torch.dtype:
        return self.normal.dtype

    def maps(self) -> dict[str, Tensor]:
        """The four maps by name, in the order of :data:`MAP_NAMES` (the tensors themselves)."""
        return {k: getattr(self, k) for k in MAP_NAMES}

    def __repr__(self) -> str:
        h, w = self.resolution
        return (f"SVBRDF(batch={self.batch_size}, resolution={h}x{w}, dtype={self.dtype}, "
                f"device={self.device}, render={'yes' if self.render is not None else 'no'}, "
                f"name={self.name!r})")

    def _apply(self, fn: Callable[[Tensor], Tensor]) -> SVBRDF:
        """A new SVBRDF with ``fn`` applied to every map (and the render tile), not re-validated."""
        return SVBRDF(**{k: fn(v) for k, v in self.maps().items()},
                      render=None if self.render is None else fn(self.render), name=self.name, check=False)

    def to(self, *args: Any, **kwargs: Any) -> SVBRDF:
        """A copy with every tensor moved/converted by ``Tensor.to(*args, **kwargs)`` (device, dtype)."""
        return self._apply(lambda t: t.to(*args, **kwargs))

    def detach(self) -> SVBRDF:
        """A copy whose tensors are detached from the autograd graph (sharing storage)."""
        return self._apply(lambda t: t.detach())

    def resized(self, size: int | tuple[int, int]) -> SVBRDF:
        """The maps (and render tile) resampled to ``size`` (N or (H, W)) texels: area averages
        when no axis grows, bilinear interpolation otherwise; normals renormalised. Returns self
        when the size is already that."""
        h, w = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
        if h < 1 or w < 1:
            raise MaterialError(f"cannot resize a material to {h}x{w} texels")
        if self.resolution == (h, w):
            return self
        maps = {k: resample_texels(v, (h, w)) for k, v in self.maps().items()}
        maps["normal"] = maps["normal"] / torch.linalg.vector_norm(maps["normal"], dim=1, keepdim=True).clamp_min(1e-12)
        render = None if self.render is None else resample_texels(self.render, (h, w))
        return SVBRDF(**maps, render=render, name=self.name)

    def requires_grad_(self, requires_grad: bool = True) -> SVBRDF:
        """Set ``requires_grad`` on the four maps (leaf tensors) in place; returns self."""
        for t in self.maps().values():
            t.requires_grad_(requires_grad)
        return self

    def __getitem__(self, index: int | slice | Sequence[int] | Tensor) -> SVBRDF:
        """Select materials along the batch; an int keeps the batch dimension (B = 1)."""
        if isinstance(index, (int, np.integer)) or (isinstance(index, Tensor) and index.ndim == 0):
            i = int(index)
            if not -self.batch_size <= i < self.batch_size:
                raise IndexError(f"material index {i} is out of range for a batch of {self.batch_size}")
            i %= self.batch_size
            return self._apply(lambda t: t[i:i + 1])
        if isinstance(index, tuple):
            raise TypeError("SVBRDF indexing selects materials only: use an int, slice or index list")
        sel = self._apply(lambda t: t[index])
        if sel.batch_size == 0:
            raise IndexError(f"index {index!r} selects no material from a batch of {self.batch_size}")
        return sel

    def __iter__(self) -> Iterator[SVBRDF]:
        """Iterate over single materials (each with B = 1)."""
        return (self[i] for i in range(self.batch_size))

    @classmethod
    def cat(cls, items: Sequence[SVBRDF]) -> SVBRDF:
        """Concatenate materials of one resolution, dtype and device along the batch.

        The render tiles are kept only if every item has one; the name only if all names agree.
        """
        items = list(items)
        if not items or not all(isinstance(s, SVBRDF) for s in items):
            raise MaterialError("SVBRDF.cat needs a non-empty list of SVBRDF objects")
        res = {s.resolution for s in items}
        if len(res) != 1:
            raise MaterialError(f"SVBRDF.cat: materials have different resolutions {sorted(res)}")
        renders = [s.render for s in items]
        names = {s.name for s in items}
        return cls(**{k: torch.cat([getattr(s, k) for s in items]) for k in MAP_NAMES},
                   render=torch.cat(renders) if all(r is not None for r in renders) else None,
                   name=names.pop() if len(names) == 1 else None)

    # ---- encoded form and constants --------------------------------------------------------

    def encoded(self) -> Tensor:
        """``(B, 10, H, W)`` encoded maps (see :func:`encode_maps`); differentiable."""
        return encode_maps(self.normal, self.diffuse, self.roughness, self.specular)

    @classmethod
    def from_encoded(cls, t: Tensor, *, render: Tensor | None = None, name: str | None = None,
                     check: bool = True) -> SVBRDF:
        """Build from ``(B, 10, H, W)`` or ``(10, H, W)`` encoded maps (see :func:`decode_maps`)."""
        return cls(*decode_maps(t), render=render, name=name, check=check)

    @classmethod
    def constant(cls, normal: Sequence[float] = (0.0, 0.0, 1.0), diffuse: float | Sequence[float] = 0.5,
                 roughness: float = 0.5, specular: float | Sequence[float] = 0.04,
                 size: int | tuple[int, int] = 64, batch: int = 1, *,
                 device: str | torch.device | None = None, dtype: torch.dtype = torch.float32) -> SVBRDF:
        """A homogeneous material.

        Args:
            normal: a 3-vector, normalised here (must have z >= 0).
            diffuse, specular: a scalar (grey) or an RGB triple in [0, 1].
            roughness: a scalar in [0, 1].
            size: ``H = W = size`` or ``(H, W)``.
            batch: number of (identical) materials B.
            device, dtype: of the maps (default CPU float32).

        Returns:
            An SVBRDF whose maps are independent tensors (safe to ``requires_grad_`` and modify).
        """
        h, w = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
        if h < 1 or w < 1 or batch < 1:
            raise MaterialError(f"SVBRDF.constant needs size >= 1 and batch >= 1, got size {(h, w)}, batch {batch}")

        def fill(v: Any, c: int, what: str) -> Tensor:
            v = torch.as_tensor(v, dtype=torch.float64).reshape(-1)
            if v.numel() == 1:
                v = v.expand(c)
            if v.numel() != c:
                raise MaterialError(f"SVBRDF.constant: {what} needs 1 or {c} values, got {v.numel()}")
            return v.to(dtype).view(1, c, 1, 1).expand(batch, c, h, w).to(device).clone()

        n = torch.as_tensor(normal, dtype=torch.float64).reshape(-1)
        if n.numel() != 3 or not torch.isfinite(n).all() or float(n.norm()) == 0:
            raise MaterialError(f"SVBRDF.constant: normal must be a non-zero 3-vector, got {normal!r}")
        return cls(normal=fill(n / n.norm(), 3, "normal"), diffuse=fill(diffuse, 3, "diffuse"),
                   roughness=fill(roughness, 1, "roughness"), specular=fill(specular, 3, "specular"))

    # ---- files ------------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path, *, strict: bool = False, srgb_albedo: bool = False) -> SVBRDF:
        """Load one material (B = 1) from a strip PNG, a folder of maps, or a layered EXR.

        Args:
            path: a ``.png`` (or ``.jpg``) strip of 4 or 5 tiles, a folder, or a ``.exr`` file;
                see the module docstring for each layout.
            strict: raise instead of warning about bad file normals or unequal roughness channels.
            srgb_albedo: decode diffuse and specular from sRGB to linear (for every format). The
                default keeps stored values as they are: they are the linear albedos (the module
                docstring's convention). The render tile is never decoded.

        Returns:
            An SVBRDF with B = 1, float32 on the CPU, ``name`` = the file or folder stem.

        Raises:
            ImageFileError: missing path, unreadable / truncated / non-image file, unsupported type,
                a folder missing a map file.
            MaterialError: wrong strip width, missing EXR layers, maps of different sizes or wrong
                channel counts, values outside [0, 1] or non-finite; ``strict`` problems.
        """
        path = Path(path)
        render = None
        if path.is_dir():
            maps = _read_folder(path)
        elif not path.exists():
            raise ImageFileError(f"{path}: no such file or folder")
        elif path.suffix.lower() == ".exr":
            maps, render = _read_layered_exr(path)
        else:
            maps, render = _read_strip(path)
        for k in MAP_NAMES:  # a loop, not a comprehension: warnings' stacklevel points at the caller
            maps[k] = _fit_channels(maps[k], k, path, strict)
        maps["normal"] = _clean_file_normals(maps["normal"], path, strict)
        tensors = {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)).permute(2, 0, 1)
                   for k, v in maps.items()}
        if srgb_albedo:
            for k in ("diffuse", "specular"):
                tensors[k] = srgb_to_linear(tensors[k])
        if render is not None:
            render = torch.from_numpy(np.ascontiguousarray(render, dtype=np.float32)).permute(2, 0, 1)
        try:
            return cls(**tensors, render=render, name=path.stem or path.name)
        except MaterialError as e:
            raise MaterialError(f"{path}: {e}") from None

    def save(self, path: str | Path, *, include_render: bool = True, bits: int = 8) -> None:
        """Save this single material (B must be 1; save ``svbrdf[i]`` for each i of a batch).

        The format follows the suffix:

        * ``.png``: a strip ``[normal | diffuse | roughness | specular]`` of encoded values, or the
          5-tile ``[render | ...]`` when :attr:`render` is set and ``include_render`` (render values
          clipped to [0, 1]); ``bits`` = 8 or 16.
        * ``.exr``: layered float32 EXR (normal as the raw unit vector; ``render.R/G/B`` included
          when present and ``include_render``).
        * no suffix (or an existing folder): a folder with ``normal.png``, ``diffuse.png``,
          ``roughness.png`` (grey) and ``specular.png`` (encoded values, ``bits`` deep).

        Raises:
            MaterialError: B != 1.
            ImageFileError: an unsupported suffix, or the file cannot be written.
        """
        if self.batch_size != 1:
            raise MaterialError(f"save writes one material per path, this SVBRDF holds {self.batch_size}; "
                                "save svbrdf[i] for each i")
        path = Path(path)
        suffix = path.suffix.lower()
        maps = {k: v[0].detach().cpu().float().permute(1, 2, 0).numpy() for k, v in self.maps().items()}
        render = None
        if include_render and self.render is not None:
            render = self.render[0].detach().cpu().float().permute(1, 2, 0).numpy()
        if suffix == ".exr" and not path.is_dir():
            chans = {}
            for k, layer in _EXR_LAYERS.items():
                chans.update({f"{k}.{c}": maps[k][..., i] for i, c in enumerate(layer)})
            if render is not None:
                chans.update({f"render.{c}": render[..., i] for i, c in enumerate("RGB")})
            write_exr(path, chans)
            return
        enc = dict(maps, normal=(maps["normal"] + 1) / 2)
        if suffix == ".png" and not path.is_dir():
            tiles = [enc["normal"], enc["diffuse"], np.repeat(enc["roughness"], 3, -1), enc["specular"]]
            if render is not None:
                tiles.insert(0, render)
            write_png(path, np.concatenate(tiles, axis=1), bits=bits)
        elif suffix == "" or path.is_dir():
            for k in MAP_NAMES:
                write_png(path / f"{k}.png", enc[k], bits=bits)
        else:
            raise ImageFileError(f"{path}: cannot save as {suffix!r}: use .png (strip), .exr (layered) "
                                 "or a path without suffix (folder of PNGs)")


# ---- helpers -------------------------------------------------------------------------------------


def _as_batched(t: Any, what: str) -> Tensor:
    """Tensor-ify (arrays -> float32) and add a batch dimension to a (C, H, W) map."""
    if not isinstance(t, Tensor):
        try:
            t = torch.as_tensor(np.asarray(t, dtype=np.float32))
        except (TypeError, ValueError) as e:
            raise MaterialError(f"{what} must be a tensor or array of numbers ({e})") from None
    if not t.is_floating_point():
        raise MaterialError(f"{what} must be floating point with values in [0, 1], got {t.dtype} "
                            "(convert 8-bit images with t.float() / 255)")
    return t.unsqueeze(0) if t.ndim == 3 else t


def _read_strip(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    img = read_image(path)
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, -1)
    img = img[..., :3]
    h, w = img.shape[:2]
    if w == 4 * h:
        tiles, render = [img[:, i * h:(i + 1) * h] for i in range(4)], None
    elif w == 5 * h:
        tiles, render = [img[:, i * h:(i + 1) * h] for i in range(1, 5)], img[:, :h]
    else:
        raise MaterialError(f"{path}: an SVBRDF strip must be 4 or 5 square tiles wide (width {4 * h} "
                            f"or {5 * h} for height {h}), got {w}x{h} (width x height)")
    maps = dict(zip(MAP_NAMES, tiles))
    maps["normal"] = maps["normal"] * 2 - 1  # strip tiles hold encoded normals
    return maps, render


def _read_folder(path: Path) -> dict[str, np.ndarray]:
    maps = {}
    for k in MAP_NAMES:
        found = [path / f"{k}{s}" for s in (".png", ".exr") if (path / f"{k}{s}").is_file()]
        if not found:
            present = sorted(p.name for p in path.iterdir())
            listing = ", ".join(present[:12]) + (", ..." if len(present) > 12 else "") or "nothing"
            raise ImageFileError(f"{path}: missing the {k} map ({k}.png or {k}.exr); the folder holds {listing}")
        if len(found) > 1:
            raise ImageFileError(f"{path}: both {k}.png and {k}.exr exist; keep one")
        img = read_image(found[0])
        if k == "normal" and found[0].suffix == ".png":
            img = img[..., :3] * 2 - 1  # PNG normals are encoded; EXR normals are raw vectors
        maps[k] = img
    sizes = {k: v.shape[:2] for k, v in maps.items()}
    if len(set(sizes.values())) != 1:
        listed = ", ".join(f"{k} {s[1]}x{s[0]}" for k, s in sizes.items())
        raise MaterialError(f"{path}: maps differ in size ({listed}, width x height); they must match")
    return maps


def _read_layered_exr(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    ch = read_exr_channels(path)
    maps = {}
    for k, layer in _EXR_LAYERS.items():
        names = [f"{k}.{c}" for c in layer]
        if k == "roughness" and "roughness.Y" not in ch and "roughness.R" in ch:
            names = [f"roughness.{c}" for c in "RGB" if f"roughness.{c}" in ch]
        missing = [n for n in names if n not in ch]
        if missing:
            raise MaterialError(f"{path}: EXR lacks channels {missing}; a layered SVBRDF EXR has normal.R/G/B, "
                                f"diffuse.R/G/B, roughness.Y, specular.R/G/B (it has {list(ch)})")
        maps[k] = np.stack([ch[n] for n in names], -1)
    render = None
    if all(f"render.{c}" in ch for c in "RGB"):
        render = np.stack([ch[f"render.{c}"] for c in "RGB"], -1)
    return maps, render


def _fit_channels(a: np.ndarray, k: str, path: Path, strict: bool) -> np.ndarray:
    """Bring a map read from a file to its channel count (drop alpha, grey -> RGB, RGB roughness -> 1)."""
    if a.shape[-1] == 4:
        a = a[..., :3]
    if k in ("diffuse", "specular") and a.shape[-1] == 1:
        a = np.repeat(a, 3, -1)
    if k == "roughness" and a.shape[-1] == 3:
        spread = float(np.abs(a - a[..., :1]).max())
        if spread > ROUGHNESS_CHANNEL_TOL + 1e-6:
            msg = (f"{path}: roughness map has 3 channels that differ by up to {spread:.4g} (> 1/255); "
                   "roughness is grey")
            if strict:
                raise MaterialError(msg)
            warnings.warn(msg + "; using the first (red) channel", stacklevel=3)
        a = a[..., :1]
    if a.shape[-1] != MAP_CHANNELS[k]:
        raise MaterialError(f"{path}: {k} map has {a.shape[-1]} channel(s), expected {MAP_CHANNELS[k]}")
    return a


def _clean_file_normals(n: np.ndarray, path: Path, strict: bool) -> np.ndarray:
    """Raw (decoded) file normals (H, W, 3) -> unit vectors with z >= NORMAL_MIN_Z.

    Warns (or, ``strict``, raises) when more than 1% of texels are off unit length by > 0.05 or any
    has z <= 0. Texels already unit length to 1e-6 with z >= NORMAL_MIN_Z are returned unchanged, so
    float32 EXR normals round-trip exactly.
    """
    n64 = n.astype(np.float64)
    if not np.isfinite(n64).all():
        bad = int((~np.isfinite(n64)).any(-1).sum())
        raise MaterialError(f"{path}: normal map has NaN or Inf at {bad} texels")
    length = np.linalg.norm(n64, axis=-1)
    off = np.abs(length - 1) > FILE_NORMAL_TOL
    below = n64[..., 2] <= 0
    total = off.size
    if off.mean() > FILE_NORMAL_FRACTION or below.any():
        msg = (f"{path}: normal map has {int(off.sum())} of {total} texels ({100 * off.mean():.1f}%) off unit "
               f"length by > {FILE_NORMAL_TOL} and {int(below.sum())} with z <= 0")
        if strict:
            raise MaterialError(msg)
        warnings.warn(msg + f"; clamped to z >= {NORMAL_MIN_Z} and renormalised (strict=True makes this an error)",
                      stacklevel=3)
    clamped = n64.copy()
    clamped[..., 2] = np.maximum(clamped[..., 2], NORMAL_MIN_Z)
    unit = clamped / np.linalg.norm(clamped, axis=-1, keepdims=True)
    keep = (np.abs(length - 1) <= 1e-6) & (n64[..., 2] >= NORMAL_MIN_Z)
    return np.where(keep[..., None], n, unit).astype(np.float32)
