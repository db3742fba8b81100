"""Augmentations of SVBRDF maps that keep the physics right.

Maps are a dict of tensors ``{"normal", "diffuse", "roughness", "specular"}`` (and optionally
``"render"``), each ``(..., C, H, W)``: one material ``(C, H, W)`` or a batch ``(B, C, H, W)``.
Conventions (docs/conventions.md): row 0 is the top of the sample, the tangent frame has x to the right and
y *up*, so the normal's x/y components must follow every spatial transform of the grid:

==================  =====================================================================
horizontal flip     columns reversed; n_x -> -n_x
vertical flip       rows reversed; n_y -> -n_y
rotation by k       the grid turned k x 90 degrees counter-clockwise *as displayed*
                    (``torch.rot90(t, k, (-2, -1))``); (n_x, n_y) turned the same way:
                    k = 1: (n_x, n_y) -> (-n_y, n_x)
crop                a window of the grid; vectors unchanged
==================  =====================================================================

A material transformed this way, lit and viewed from directions transformed the same way (in the
tangent frame, :func:`transform_directions`), has the transformed reflectance image: this is what
``tests/test_datasets.py`` checks with the BRDF itself. The scalar maps and a ``render`` tile are
moved as images only (a dataset's render tile is then only as consistent as its capture geometry
is symmetric: true for the Deschaintre 2018 flash photos, not for this project's LCD rig).

Jitter (optional, per material): diffuse albedo multiplied by a per-channel factor
``exp(N(0, albedo_jitter))`` and roughness by ``exp(N(0, roughness_jitter))``, both clamped to
[0, 1]; normals and the specular albedo are left alone (ks of metals vs dielectrics is physics,
not style).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import MaterialError

MAP_KEYS = ("normal", "diffuse", "roughness", "specular")


def _rotate_xy(nx: Tensor, ny: Tensor, k: int) -> tuple[Tensor, Tensor]:
    k %= 4
    if k == 0:
        return nx, ny
    if k == 1:
        return -ny, nx
    if k == 2:
        return -nx, -ny
    return ny, -nx


def transform_normal(normal: Tensor, *, k: int = 0, hflip: bool = False, vflip: bool = False) -> Tensor:
    """Move a normal map ``(..., 3, H, W)``: flips first (horizontal, then vertical), then k x 90 degrees
    counter-clockwise; the vectors' x/y components are transformed with the grid."""
    nx, ny, nz = normal[..., 0:1, :, :], normal[..., 1:2, :, :], normal[..., 2:3, :, :]
    if hflip:
        nx = -nx
    if vflip:
        ny = -ny
    nx, ny = _rotate_xy(nx, ny, k)
    return transform_image(torch.cat([nx, ny, nz], dim=-3), k=k, hflip=hflip, vflip=vflip)


def transform_image(img: Tensor, *, k: int = 0, hflip: bool = False, vflip: bool = False) -> Tensor:
    """Move a scalar/colour image ``(..., C, H, W)`` (no vector components): flips, then rotation."""
    if hflip:
        img = torch.flip(img, dims=(-1,))
    if vflip:
        img = torch.flip(img, dims=(-2,))
    if k % 4:
        img = torch.rot90(img, k % 4, dims=(-2, -1))
    return img


def transform_directions(v: Tensor, *, k: int = 0, hflip: bool = False, vflip: bool = False) -> Tensor:
    """The same transform applied to tangent-frame direction vectors ``(..., 3)`` (x right, y up)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    if hflip:
        x = -x
    if vflip:
        y = -y
    x, y = _rotate_xy(x, y, k)
    return torch.stack([x, y, z], dim=-1)


def transform_maps(maps: dict[str, Tensor], *, k: int = 0, hflip: bool = False, vflip: bool = False) -> dict[str, Tensor]:
    """Apply one element of the square's symmetry group to every map (normals as vectors).

    Keys other than the four maps and ``render`` are passed through unchanged.
    """
    out = dict(maps)
    for key, t in maps.items():
        if key == "normal":
            out[key] = transform_normal(t, k=k, hflip=hflip, vflip=vflip)
        elif key in MAP_KEYS or key == "render":
            out[key] = transform_image(t, k=k, hflip=hflip, vflip=vflip)
    return out


def crop_maps(maps: dict[str, Tensor], top: int, left: int, height: int, width: int | None = None) -> dict[str, Tensor]:
    """The window rows ``top .. top + height - 1``, columns ``left .. left + width - 1`` of every map."""
    width = height if width is None else width
    H, W = maps["normal"].shape[-2:]
    if top < 0 or left < 0 or top + height > H or left + width > W or height < 1 or width < 1:
        raise MaterialError(f"crop {height}x{width} at ({top}, {left}) does not fit maps of {H}x{W}")
    out = dict(maps)
    for key, t in maps.items():
        if key in MAP_KEYS or key == "render":
            out[key] = t[..., top:top + height, left:left + width]
    return out


@dataclass(frozen=True)
class Augment:
    """Random physically consistent augmentation of one material's maps (``(C, H, W)`` tensors).

    Attributes:
        flips: random horizontal and vertical flips (each with probability 1/2).
        rotations: a random multiple of 90 degrees (uniform over 0..3).
        crop: output size of a random square crop (None: keep the size; must not exceed it).
        albedo_jitter: sigma of the log-normal per-channel factor on the diffuse albedo (0: off).
        roughness_jitter: sigma of the log-normal factor on the roughness (0: off).
    """

    flips: bool = True
    rotations: bool = True
    crop: int | None = None
    albedo_jitter: float = 0.0
    roughness_jitter: float = 0.0

    def __post_init__(self):
        if self.crop is not None and self.crop < 1:
            raise MaterialError(f"crop must be a positive size or None, got {self.crop}")
        if self.albedo_jitter < 0 or self.roughness_jitter < 0:
            raise MaterialError("jitter sigmas must be >= 0")

    def __call__(self, maps: dict[str, Tensor], generator: torch.Generator | None = None) -> dict[str, Tensor]:
        """Augment ``maps``; ``generator`` (CPU) makes the draw reproducible."""
        def draw(n: int) -> Tensor:
            return torch.rand(n, generator=generator)

        u = draw(8)  # a fixed number of draws, whatever is switched on
        if self.crop is not None:
            H, W = maps["normal"].shape[-2:]
            if self.crop > min(H, W):
                raise MaterialError(f"crop {self.crop} is larger than the maps ({H}x{W})")
            top = int(u[0] * (H - self.crop + 1))
            left = int(u[1] * (W - self.crop + 1))
            maps = crop_maps(maps, min(top, H - self.crop), min(left, W - self.crop), self.crop)
        hflip = bool(self.flips and u[2] < 0.5)
        vflip = bool(self.flips and u[3] < 0.5)
        k = int(u[4] * 4) % 4 if self.rotations else 0
        maps = transform_maps(maps, k=k, hflip=hflip, vflip=vflip)
        noise = torch.randn(4, generator=generator)
        if self.albedo_jitter > 0:
            f = torch.exp(self.albedo_jitter * noise[:3]).view(3, 1, 1).to(maps["diffuse"])
            maps = dict(maps, diffuse=(maps["diffuse"] * f).clamp(0.0, 1.0))
        if self.roughness_jitter > 0:
            f = float(torch.exp(self.roughness_jitter * noise[3]))
            maps = dict(maps, roughness=(maps["roughness"] * f).clamp(0.0, 1.0))
        return maps
