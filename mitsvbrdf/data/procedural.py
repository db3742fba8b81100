"""Procedural SVBRDFs: a seeded, vectorised generator of real-looking material maps.

Usage::

    from mitsvbrdf.data import procedural
    batch = procedural.generate(32, size=256, seed=0)            # SVBRDF, maps (32, C, 256, 256)
    one = procedural.generate(1, size=256, seed=0, start=17)      # == batch item 17 of a longer run
    procedural.family_of(17, seed=0)                              # which family item 17 belongs to

Determinism: material ``i`` of stream ``seed`` is a pure function of ``(seed, i, families, size,
bump, dark_metals)``: every random number it uses comes from its own ``torch.Generator`` seeded with a hash of
``(seed, i)``, drawn on the CPU, so it is the same whatever batch, worker or device it is built in
(up to floating-point rounding on other devices). Random spectra are drawn in cycles per sample,
independently of ``size``, so one material generated at 64 px and at 256 px shows the same
structure (the small one lacks the finest detail).

Families (:data:`FAMILIES`) and what varies within them:

===============  ================================================================================
tiles            square/rectangular/mosaic tiles, running or stack bond, rotated; grout, bevels,
                 per-tile tilt and colour; glazed (glossy) or matte
bricks           brick courses with mortar, chipped edges, strong per-brick colour variation
planks           wood boards with gaps and staggered ends, ring grain with warp, fibres; varnished
                 or raw
stones           cobbles / flagstones from Voronoi cells: domed stones, gaps, rough texture
leather          Voronoi creases, domed cells, pores; dyed colours from near-black to white
plastic          orange-peel bumps, regular dot/dimple grids or stippled plastic/rubber
brushed_metal    anisotropic streaks (height and correlated roughness), smudges; coloured metals
hammered_metal   dimpled metal (Voronoi dents), optional patina
scratched        glossy metal or paint with line scratches and hairline wear
paint            peeling/cracked paint over rust or metal, or metallic flake car paint
fabric           woven threads (plain, twill, basket) with fibre noise, two thread colours
mixture          noise mixtures: rust on metal, veined marble, porous concrete, two-layer plaster
===============  ================================================================================

Maps follow :class:`mitsvbrdf.SVBRDF` (normal unit, kd/ks/roughness in [0, 1], albedos in the
encoding :mod:`mitsvbrdf.svbrdf` documents, the one its strips are loaded in). Roughness lies in
[0.02, 1]; ks spans dielectrics (~0.02-0.08 grey) to coloured metals (up to ~1); kd spans black
(pure metals, kd = 0) to bright (~0.9). Widened to cover the dataset samples
(docs/benchmarks/data_statistics.md): a quarter of the materials get a steep relief
(:data:`STEEP_FRACTION`), a fifth saturated colours whose channels reach 0 or 1
(:data:`SATURATED_FRACTION`), a third of metal albedos kd = 0 (:data:`METAL_BLACK_KD`), and,
with ``dark_metals > 0``, that fraction of materials get dark pure metals (F0 scaled into
0.03-0.3, :data:`DARK_METAL_F0`). Normals
come from a height field (sample units, side = 1) by :func:`height_to_normal`; the paint family's
metallic flakes add a per-flake slope field on top.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Callable, Sequence

import torch
from torch import Tensor

from ..errors import MaterialError
from ..svbrdf import SVBRDF
from .noise import (cellular, col, grid, lerp, lookup, lookup_flat, rotate, smoothstep,
                    spectral_noise)

ROUGHNESS_MIN = 0.02
#: Fraction of metal albedos drawn with kd = 0 exactly.
METAL_BLACK_KD = 0.35
#: Fraction of materials with a steep relief: the relief multiplier times logu(*STEEP_RELIEF).
STEEP_FRACTION, STEEP_RELIEF = 0.25, (1.5, 4.0)
#: Range of the F0 factor of a darkened pure metal (``dark_metals`` of :func:`generate`): oxidised,
#: anodised or dark alloys, whose coloured F0 of 0.03-0.3 no palette metal reaches (the dataset's
#: blue riveted plate, 2_svbrdf: kd = 0, ks mean 0.06-0.1, docs/benchmarks/data_statistics.md).
DARK_METAL_F0 = (0.08, 0.4)
#: Fraction of materials with saturated colours: kd and ks pushed away from their luminance by a
#: factor u(*SATURATION), then clamped (so channels reach 0 or 1, as in saturated artist maps).
SATURATED_FRACTION, SATURATION = 0.2, (1.5, 3.0)
#: Highest spectral frequency drawn for detail fields (cycles per sample side).
F_DETAIL = 128
#: Highest spectral frequency drawn for large-scale fields.
F_SHAPE = 24


# ---- per-material random draws -------------------------------------------------------------------


def material_seed(seed: int, index: int, salt: str = "material") -> int:
    """63-bit seed of material ``index`` in stream ``seed`` (a hash, stable across platforms)."""
    h = hashlib.blake2b(f"{salt}:{int(seed)}:{int(index)}".encode(), digest_size=8).digest()
    return int.from_bytes(h, "little") & ((1 << 63) - 1)


class Draw:
    """Random draws for one material from its own CPU ``torch.Generator``."""

    def __init__(self, seed: int):
        self.g = torch.Generator().manual_seed(int(seed))

    def u(self, a: float = 0.0, b: float = 1.0) -> float:
        return a + (b - a) * float(torch.rand((), generator=self.g))

    def logu(self, a: float, b: float) -> float:
        return math.exp(self.u(math.log(a), math.log(b)))

    def int(self, a: int, b: int) -> int:
        """Uniform integer in [a, b]."""
        return int(torch.randint(a, b + 1, (), generator=self.g))

    def p(self, prob: float) -> bool:
        return self.u() < prob

    def pick(self, items: Sequence, weights: Sequence[float] | None = None):
        if weights is None:
            return items[self.int(0, len(items) - 1)]
        w = torch.tensor(weights, dtype=torch.float64)
        return items[int(torch.multinomial(w / w.sum(), 1, generator=self.g))]

    def colour(self, palette: Sequence[tuple[float, float, float]], hue: float = 0.08,
               value: float = 0.2) -> tuple[float, float, float]:
        """A palette colour with per-channel (``hue``) and overall (``value``) log-normal jitter."""
        base = self.pick(palette)
        v = math.exp(value * self.normal())
        return tuple(min(1.0, max(0.0, c * v * math.exp(hue * self.normal()))) for c in base)

    def normal(self) -> float:
        return float(torch.randn((), generator=self.g))

    def spectrum(self, fmax: int) -> Tensor:
        """(2F+1, F+1) complex standard-normal spectral coefficients (see noise.spectral_noise)."""
        return torch.view_as_complex(torch.randn(2 * fmax + 1, fmax + 1, 2, generator=self.g) * math.sqrt(0.5))

    def table(self, n: int, k: int) -> Tensor:
        """(n, n, k) uniform [0, 1) per-cell values."""
        return torch.rand(n, n, k, generator=self.g)


# ---- palettes (values as stored in the maps) ------------------------------------------------------

TILE = [(0.85, 0.85, 0.82), (0.8, 0.72, 0.55), (0.02, 0.02, 0.02), (0.55, 0.25, 0.12),
        (0.08, 0.18, 0.5), (0.15, 0.35, 0.2), (0.4, 0.4, 0.4), (0.1, 0.45, 0.45), (0.8, 0.6, 0.15),
        (0.5, 0.06, 0.05), (0.92, 0.92, 0.92), (0.25, 0.25, 0.27)]
BRICK = [(0.45, 0.16, 0.09), (0.55, 0.25, 0.14), (0.35, 0.12, 0.08), (0.6, 0.45, 0.3),
         (0.3, 0.28, 0.27), (0.22, 0.1, 0.07), (0.7, 0.62, 0.5), (0.85, 0.84, 0.8)]
MORTAR = [(0.45, 0.45, 0.44), (0.7, 0.68, 0.62), (0.15, 0.15, 0.15), (0.55, 0.48, 0.38), (0.3, 0.28, 0.25)]
WOOD = [((0.62, 0.42, 0.22), (0.42, 0.25, 0.11)), ((0.78, 0.6, 0.38), (0.6, 0.38, 0.18)),
        ((0.3, 0.17, 0.08), (0.14, 0.07, 0.03)), ((0.55, 0.25, 0.12), (0.35, 0.13, 0.06)),
        ((0.85, 0.7, 0.5), (0.7, 0.52, 0.32)), ((0.06, 0.04, 0.03), (0.02, 0.015, 0.01)),
        ((0.55, 0.52, 0.48), (0.35, 0.32, 0.3)), ((0.88, 0.85, 0.8), (0.7, 0.66, 0.6))]
STONE = [(0.45, 0.45, 0.45), (0.7, 0.55, 0.38), (0.2, 0.21, 0.23), (0.1, 0.1, 0.1),
         (0.75, 0.72, 0.65), (0.5, 0.3, 0.22), (0.35, 0.27, 0.2), (0.88, 0.87, 0.85), (0.3, 0.32, 0.28)]
SOIL = [(0.12, 0.09, 0.06), (0.3, 0.28, 0.25), (0.05, 0.05, 0.05), (0.45, 0.4, 0.32), (0.2, 0.22, 0.12)]
LEATHER = [(0.015, 0.013, 0.012), (0.12, 0.06, 0.03), (0.55, 0.33, 0.16), (0.4, 0.05, 0.04),
           (0.04, 0.06, 0.15), (0.45, 0.2, 0.07), (0.3, 0.3, 0.3), (0.85, 0.83, 0.8), (0.08, 0.18, 0.1)]
PAINT = [(0.9, 0.9, 0.9), (0.02, 0.02, 0.02), (0.7, 0.05, 0.04), (0.85, 0.35, 0.05), (0.9, 0.75, 0.1),
         (0.1, 0.5, 0.15), (0.05, 0.2, 0.7), (0.3, 0.6, 0.85), (0.35, 0.1, 0.5), (0.9, 0.45, 0.6),
         (0.5, 0.5, 0.5), (0.95, 0.93, 0.88)]
FABRIC = PAINT + [(0.1, 0.15, 0.3), (0.55, 0.5, 0.35), (0.3, 0.04, 0.06), (0.85, 0.8, 0.68), (0.2, 0.2, 0.22)]
RUST = [(0.35, 0.12, 0.05), (0.5, 0.22, 0.08), (0.25, 0.1, 0.05), (0.6, 0.35, 0.15)]
#: Specular albedo (F0) of metals, linear RGB.
METAL = [(0.97, 0.96, 0.91), (0.91, 0.92, 0.92), (1.0, 0.78, 0.34), (0.95, 0.64, 0.54),
         (0.89, 0.79, 0.43), (0.56, 0.57, 0.58), (0.55, 0.56, 0.55), (0.54, 0.5, 0.45),
         (0.66, 0.61, 0.53), (0.66, 0.68, 0.69), (0.62, 0.62, 0.62), (0.8, 0.55, 0.35),
         (0.3, 0.45, 0.8), (0.8, 0.25, 0.25)]


IRON = [(0.56, 0.57, 0.58), (0.62, 0.62, 0.62), (0.55, 0.56, 0.55), (0.66, 0.68, 0.69)]


def _metal(d: Draw) -> tuple[float, float, float]:
    return d.colour(METAL, hue=0.03, value=0.08)


def _dielectric_ks(d: Draw, lo: float = 0.02, hi: float = 0.08) -> tuple[float, float, float]:
    v = d.u(lo, hi)
    return (v, v, v)


def _metal_kd(d: Draw) -> tuple[float, float, float]:
    if d.p(METAL_BLACK_KD):  # pure metal: no diffuse at all (as in the dataset's metals)
        return (0.0, 0.0, 0.0)
    v = d.logu(0.003, 0.05)
    return tuple(v * d.u(0.7, 1.0) for _ in range(3))


# ---- family machinery ----------------------------------------------------------------------------


@dataclass
class Layers:
    """A family's output for B materials: ``height`` (B, H, W) in sample units, ``kd``/``ks``
    (B, 3, H, W) (or broadcastable), ``rough`` (B, H, W); ``slope`` optional (B, 2, H, W) extra
    (dh/dx, dh/dy) in the y-up frame, added to the height's gradient (non-integrable detail)."""

    height: Tensor
    kd: Tensor
    rough: Tensor
    ks: Tensor
    slope: Tensor | None = None


@dataclass(frozen=True)
class Family:
    name: str
    sample: Callable[[Draw], tuple[str, dict]]
    build: Callable[[dict, str, int], Layers]


def _c(p: dict, key: str) -> Tensor:
    """(B, 3) colour parameter -> (B, 3, 1, 1)."""
    return p[key].reshape(-1, 3, 1, 1)


def _f(t: Tensor) -> Tensor:
    """(B, H, W) -> (B, 1, H, W)."""
    return t.unsqueeze(1)


def _sn(p: dict, key: str, size: int, beta, fmin, fmax, unit: str = "std", angle=None, aniso=None) -> Tensor:
    return spectral_noise(p[key], size, beta=beta, fmin=fmin, fmax=fmax, angle=angle, aniso=aniso, unit=unit)


def _unit_std(t: Tensor) -> Tensor:
    """A field rescaled to unit standard deviation per material (for colour/roughness modulation)."""
    return t / t.std(dim=(-2, -1), keepdim=True).clamp_min(1e-12)


def _angle(d: Draw, axis_prob: float = 0.7) -> float:
    if d.p(axis_prob):
        return d.pick([0.0, 0.0, math.pi / 2, math.pi / 4])
    return d.u(-math.pi, math.pi)


# ---- tiles and bricks ----------------------------------------------------------------------------


def _sample_tiles(d: Draw) -> tuple[str, dict]:
    n_cols = d.pick([1, 2, 2, 3, 4, 4, 5, 6, 8, 12, 16])
    aspect = d.pick([1, 1, 1, 2, 3]) if n_cols <= 8 else 1
    pitch = 1.0 / n_cols
    glossy = d.p(0.6)
    two_colour = d.p(0.25)
    p = dict(
        n_cols=float(n_cols), n_rows=float(n_cols * aspect), offset=d.pick([0.0, 0.0, 0.0, 0.5]),
        angle=_angle(d), grout=min(d.u(0.003, 0.014), 0.12 * pitch / aspect),
        bevel=min(d.logu(0.002, 0.015), 0.15 * pitch / aspect), tile_h=d.u(0.002, 0.008),
        chip=d.u(0.0, 0.0015), tilt=d.u(0.0, 0.05), surf_slope=d.logu(0.005, 0.12),
        surf_beta=d.u(1.5, 3.0), grout_slope=d.u(0.05, 0.4),
        colour=d.colour(TILE), colour2=d.colour(TILE) if two_colour else (-1.0, -1.0, -1.0),
        colour_var=d.u(0.02, 0.2), mortar=d.colour(MORTAR),
        rough=d.logu(0.02, 0.25) if glossy else d.u(0.35, 0.8), rough_var=d.u(0.0, 0.3),
        grout_rough=d.u(0.7, 1.0), ks=_dielectric_ks(d, 0.03, 0.08 if glossy else 0.05),
        grout_ks=_dielectric_ks(d, 0.02, 0.04), dirt=d.u(0.0, 0.5),
    )
    return "layout", _masonry_noise(d, p)


def _sample_bricks(d: Draw) -> tuple[str, dict]:
    n_rows = d.int(5, 16)
    ratio = d.pick([2, 2, 3, 4])
    p = dict(
        n_cols=float(max(1, round(n_rows / ratio))), n_rows=float(n_rows),
        offset=d.pick([0.5, 0.5, 0.5, 0.25, 1 / 3]), angle=d.pick([0.0, 0.0, 0.0, math.pi / 2, d.u(-0.3, 0.3)]),
        grout=d.u(0.006, 0.3 / n_rows), bevel=d.logu(0.003, 0.012), tile_h=d.u(0.004, 0.012),
        chip=d.u(0.0005, 0.004), tilt=d.u(0.0, 0.08), surf_slope=d.logu(0.05, 0.35),
        surf_beta=d.u(1.5, 2.5), grout_slope=d.u(0.2, 0.6),
        colour=d.colour(BRICK), colour2=d.colour(BRICK) if d.p(0.4) else (-1.0, -1.0, -1.0),
        colour_var=d.u(0.1, 0.35), mortar=d.colour(MORTAR),
        rough=d.u(0.5, 0.95), rough_var=d.u(0.0, 0.3), grout_rough=d.u(0.8, 1.0),
        ks=_dielectric_ks(d, 0.02, 0.05), grout_ks=_dielectric_ks(d, 0.02, 0.04), dirt=d.u(0.1, 0.8),
    )
    return "layout", _masonry_noise(d, p)


def _masonry_noise(d: Draw, p: dict) -> dict:
    p.update(table=d.table(32, 9), c_chip=d.spectrum(F_DETAIL // 2), c_surf=d.spectrum(F_DETAIL),
             c_grout=d.spectrum(F_DETAIL), c_dirt=d.spectrum(F_SHAPE))
    return p


def _build_masonry(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["angle"].device)
    xr, yr = rotate(x, y, p["angle"])
    tw, th = col(1.0 / p["n_cols"]), col(1.0 / p["n_rows"])
    row = torch.floor(yr / th)
    xs = xr + row * col(p["offset"]) * tw
    colm = torch.floor(xs / tw)
    fx, fy = xs - colm * tw, yr - row * th
    edge = torch.minimum(torch.minimum(fx, tw - fx), torch.minimum(fy, th - fy))
    cells = lookup(p["table"], row, colm)  # (B, 9, H, W)
    chip = _sn(p, "c_chip", size, 1.5, 6.0, 48.0)
    e = edge + col(p["chip"]) * chip
    g2 = col(p["grout"]) / 2
    top = smoothstep(g2, g2 + col(p["bevel"]), e)
    surf = _sn(p, "c_surf", size, p["surf_beta"], 3.0, 128.0, unit="slope") * col(p["surf_slope"])
    grout_n = _sn(p, "c_grout", size, 1.0, 20.0, 128.0, unit="slope") * col(p["grout_slope"])
    tile_h = (col(p["tile_h"]) * (0.85 + 0.3 * cells[:, 6])
              + col(p["tilt"]) * ((cells[:, 0] - 0.5) * (fx - tw / 2) + (cells[:, 1] - 0.5) * (fy - th / 2))
              + surf)
    height = lerp(grout_n, tile_h, top)
    # colours: per-tile jitter, optional second colour, dirt in the grout and on the tiles
    base = _c(p, "colour")
    alt = _c(p, "colour2")
    use_alt = (alt[:, :1] >= 0) & _f(cells[:, 8] < 0.5)
    tile_c = torch.where(use_alt, alt.clamp_min(0), base)
    jitter = torch.exp(0.12 * col(p["colour_var"]).unsqueeze(1) * (2 * cells[:, 2:5] - 1)
                       + _f(col(p["colour_var"]) * (2 * cells[:, 5] - 1)))
    dirt = smoothstep(-0.5, 2.0, _sn(p, "c_dirt", size, 2.5, 1.0, 16.0)) * col(p["dirt"])
    tile_c = tile_c * jitter * _f(1.0 - 0.3 * dirt + 0.03 * _unit_std(surf).clamp(-3, 3))
    mortar = _c(p, "mortar") * _f(1.0 - 0.5 * dirt + 0.1 * _unit_std(grout_n).clamp(-3, 3))
    t4 = _f(top)
    kd = lerp(mortar, tile_c, t4)
    rough_t = col(p["rough"]) * (1.0 + col(p["rough_var"]) * (2 * cells[:, 7] - 1)) + 0.2 * dirt
    rough = lerp(col(p["grout_rough"]), rough_t, top)
    ks = lerp(_c(p, "grout_ks"), _c(p, "ks"), t4)
    return Layers(height, kd, rough, ks)


# ---- wood planks ---------------------------------------------------------------------------------


def _sample_planks(d: Draw) -> tuple[str, dict]:
    varnished = d.p(0.5)
    early, late = d.pick(WOOD)
    v = math.exp(0.15 * d.normal())
    p = dict(
        n_boards=float(d.int(2, 9)), length=d.u(0.3, 1.5), angle=d.pick([0.0, 0.0, math.pi / 2, d.u(-0.4, 0.4)]),
        gap=d.u(0.001, 0.006), bevel=d.u(0.001, 0.006), board_h=d.u(0.001, 0.004), tilt=d.u(0.0, 0.04),
        rings=d.u(15.0, 70.0), ring_sharp=d.u(1.0, 6.0), warp=d.u(0.005, 0.04), slant=d.u(-0.15, 0.15),
        fibre_aniso=d.u(10.0, 40.0), fibre_slope=d.logu(0.005, 0.08), grain_depth=d.u(0.0, 0.0006),
        early=tuple(min(1, c * v) for c in early), late=tuple(min(1, c * v) for c in late), tint=d.u(0.05, 0.3),
        rough=d.logu(0.04, 0.35) if varnished else d.u(0.45, 0.9),
        rough_grain=d.u(-0.15, 0.05) if not varnished else d.u(0.0, 0.08),
        ks=_dielectric_ks(d, 0.035, 0.07) if varnished else _dielectric_ks(d, 0.02, 0.04),
        table=d.table(32, 6), c_warp=d.spectrum(F_SHAPE), c_fibre=d.spectrum(F_DETAIL),
    )
    return "boards", p


def _build_planks(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["angle"].device)
    xr, yr = rotate(x, y, p["angle"])
    bw, bl = col(1.0 / p["n_boards"]), col(p["length"])
    row = torch.floor(yr / bw)
    off = lookup(p["table"], row, torch.zeros_like(row))[:, 0] * bl
    xs = xr + off
    seg = torch.floor(xs / bl)
    fx, fy = xs - seg * bl, yr - row * bw
    edge = torch.minimum(torch.minimum(fy, bw - fy), torch.minimum(fx, bl - fx))
    cells = lookup(p["table"], row, seg)
    g2 = col(p["gap"]) / 2
    top = smoothstep(g2, g2 + col(p["bevel"]), edge)
    warp = _sn(p, "c_warp", size, 3.0, 1.0, 8.0)
    r = ((fy + col(p["warp"]) * warp + col(p["slant"]) * fx) * col(p["rings"]) * (0.7 + 0.6 * cells[:, 2])
         + 10.0 * cells[:, 3])
    ring = (0.5 + 0.5 * torch.sin(2 * math.pi * r)) ** col(p["ring_sharp"])
    fibre = _sn(p, "c_fibre", size, 1.0, 16.0, 128.0, angle=p["angle"], aniso=p["fibre_aniso"])
    board = col(p["board_h"]) + col(p["tilt"]) * (cells[:, 4] - 0.5) * (fy - bw / 2)
    height = top * (board - col(p["grain_depth"]) * ring
                    + fibre * col(p["fibre_slope"]) / (2 * math.pi * 40.0))
    mix = (0.75 * ring + 0.12 * fibre).clamp(0, 1)
    kd = lerp(_c(p, "early"), _c(p, "late"), _f(mix))
    tint = torch.exp(_f(col(p["tint"]) * (2 * cells[:, 0] - 1)))
    kd = kd * tint * _f(0.35 + 0.65 * top)
    rough = lerp(torch.full_like(top, 0.9), col(p["rough"]) * (1 + 0.15 * (2 * cells[:, 5] - 1))
                 + col(p["rough_grain"]) * ring, top)
    ks = _c(p, "ks") * _f(0.5 + 0.5 * top)
    return Layers(height, kd, rough, ks)


# ---- stones and cobbles --------------------------------------------------------------------------


def _sample_stones(d: Draw) -> tuple[str, dict]:
    n = d.int(3, 10)
    p = dict(
        n=float(n), jitter=d.u(0.5, 1.0), gap=d.u(0.03, 0.15) / n, round=d.u(0.06, 0.3) / n,
        profile=d.u(0.5, 1.0), stone_h=d.u(0.03, 0.12) / n, bulge=d.u(0.0, 0.6), chip=d.u(0.0, 0.03) / n,
        tex_slope=d.logu(0.03, 0.4), tex_beta=d.u(1.5, 3.0),
        colour=d.colour(STONE), colour2=d.colour(STONE) if d.p(0.5) else (-1.0, -1.0, -1.0),
        colour_var=d.u(0.05, 0.35), soil=d.colour(SOIL),
        rough=d.u(0.3, 0.85), rough_var=d.u(0.0, 0.3), worn=d.u(0.0, 0.4),
        ks=_dielectric_ks(d, 0.02, 0.06),
        table=d.table(16, 2), cell_values=d.table(16, 6).reshape(256, 6),
        c_chip=d.spectrum(F_DETAIL // 2), c_tex=d.spectrum(F_DETAIL), c_soil=d.spectrum(F_DETAIL),
    )
    return "cells", p


def _build_stones(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["n"].device)
    c = cellular(x, y, p["n"], p["table"], p["jitter"])
    vals = lookup_flat(p["cell_values"], c["id"])  # (B, 6, H, W)
    e = c["edge"] + col(p["chip"]) * _sn(p, "c_chip", size, 2.0, 4.0, 24.0)
    g2 = col(p["gap"]) / 2
    t = ((e - g2) / col(p["round"])).clamp(0, 1)
    dome = (t * t * (3 - 2 * t)) ** col(p["profile"])  # 0 in the gaps, 1 on the stone tops
    tex = _sn(p, "c_tex", size, p["tex_beta"], 3.0, 128.0, unit="slope") * col(p["tex_slope"])
    soil = _sn(p, "c_soil", size, 1.0, 20.0, 128.0, unit="slope") * 0.3
    bulge = 1 - col(p["bulge"]) * (c["f1"] * col(p["n"])) ** 2  # rounded tops
    stone_h = col(p["stone_h"]) * (0.7 + 0.6 * vals[:, 0]) * bulge
    height = dome * (stone_h + tex) + (1 - dome) * soil
    base = _c(p, "colour")
    alt = _c(p, "colour2")
    use_alt = (alt[:, :1] >= 0) & _f(vals[:, 1] < 0.5)
    sc = torch.where(use_alt, alt.clamp_min(0), base)
    jitter = torch.exp(_f(col(p["colour_var"]) * (2 * vals[:, 2] - 1))
                       + 0.1 * col(p["colour_var"]).unsqueeze(1) * (2 * vals[:, 3:6] - 1))
    texn = _unit_std(tex)
    sc = sc * jitter * _f(1 + 0.08 * texn.clamp(-3, 3))
    kd = lerp(_c(p, "soil") * _f(1 + 0.15 * _unit_std(soil).clamp(-2, 2)), sc, _f(dome))
    top = texn.clamp(-2, 2)  # worn: the texture's high points are smoother
    rough_s = col(p["rough"]) * (1 + col(p["rough_var"]) * (2 * vals[:, 4] - 1) - col(p["worn"]) * 0.25 * top)
    rough = lerp(torch.full_like(dome, 0.95), rough_s, dome)
    ks = lerp(torch.full_like(kd, 0.025), _c(p, "ks").expand_as(kd), _f(dome))
    return Layers(height, kd, rough, ks)


# ---- leather -------------------------------------------------------------------------------------


def _sample_leather(d: Draw) -> tuple[str, dict]:
    n = d.int(10, 30)
    p = dict(
        n=float(n), jitter=d.u(0.7, 1.0), crease=d.u(0.1, 0.3) / n, depth=d.u(0.15, 0.6) / n / 10,
        dome=d.u(0.0, 1.0), pores=d.u(0.0, 1.0), pore_depth=d.u(0.0002, 0.001), fine_slope=d.logu(0.01, 0.1),
        colour=d.colour(LEATHER, value=0.3), mottle=d.u(0.0, 0.25), crease_dark=d.u(0.0, 0.5),
        rough=d.u(0.25, 0.8), crease_rough=d.u(0.0, 0.2), ks=_dielectric_ks(d, 0.025, 0.06),
        table=d.table(32, 2), c_pore=d.spectrum(F_DETAIL), c_mottle=d.spectrum(F_SHAPE),
        c_fine=d.spectrum(F_DETAIL),
    )
    return "cells", p


def _build_leather(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["n"].device)
    c = cellular(x, y, p["n"], p["table"], p["jitter"])
    crease = 1 - smoothstep(0.0, col(p["crease"]), c["edge"])
    r = 0.5 / col(p["n"])
    dome = (1 - (c["f1"] / r).clamp(0, 1.5) ** 2 / 2.25)
    pore_n = _sn(p, "c_pore", size, 0.0, 40.0, 128.0)
    pores = smoothstep(1.6, 2.6, pore_n) * col(p["pores"])
    fine = _sn(p, "c_fine", size, 2.0, 30.0, 128.0, unit="slope") * col(p["fine_slope"])
    depth = col(p["depth"])
    height = depth * (col(p["dome"]) * dome * 0.5 - crease) - col(p["pore_depth"]) * pores + fine
    mottle = _sn(p, "c_mottle", size, 2.5, 1.0, 20.0)
    kd = _c(p, "colour") * _f(torch.exp(col(p["mottle"]) * mottle) * (1 - col(p["crease_dark"]) * crease)
                               * (1 - 0.3 * pores))
    rough = col(p["rough"]) + col(p["crease_rough"]) * crease + 0.1 * pores
    return Layers(height, kd, rough, _c(p, "ks"))


# ---- plastic -------------------------------------------------------------------------------------


def _sample_plastic(d: Draw) -> tuple[str, dict]:
    variant = d.pick(["peel", "dots", "stipple"])
    rubber = d.p(0.2)
    n = d.int(6, 28)
    p = dict(
        slope=d.logu(0.03, 0.5), beta=d.u(2.0, 3.5), fmin=d.u(4.0, 20.0), fmax=d.u(25.0, 100.0),
        n=float(n), radius=d.u(0.2, 0.45) / n, dot_h=d.u(0.1, 0.9), sign=d.pick([1.0, 1.0, -1.0]),
        thresh=d.u(0.0, 1.2), stipple_h=d.u(0.0003, 0.002),
        colour=d.colour(PAINT, value=0.15), mottle=d.u(0.0, 0.05),
        rough=d.u(0.6, 1.0) if rubber else d.logu(0.03, 0.6), rough_var=d.u(0.0, 0.15),
        ks=_dielectric_ks(d, 0.03, 0.06), table=d.table(32, 2),
        c_bump=d.spectrum(F_DETAIL), c_mottle=d.spectrum(F_SHAPE),
    )
    return variant, p


def _build_plastic(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["n"].device)
    bump = _sn(p, "c_bump", size, p["beta"], p["fmin"], p["fmax"], unit="slope")
    if variant == "peel":
        height = bump * col(p["slope"])
        feature = bump / bump.std(dim=(1, 2), keepdim=True).clamp_min(1e-8)
    elif variant == "dots":
        c = cellular(x, y, p["n"], p["table"], torch.zeros_like(p["n"]))
        r = col(p["radius"])
        q = (1 - (c["f1"] / r) ** 2).clamp_min(0)
        dome = torch.sqrt(q + 1e-4) - 0.01
        height = col(p["sign"]) * col(p["dot_h"]) * r * dome.clamp_min(0) + bump * 0.01 * col(p["slope"])
        feature = dome
    else:
        field = bump / bump.std(dim=(1, 2), keepdim=True).clamp_min(1e-8)
        plate = smoothstep(col(p["thresh"]) - 0.3, col(p["thresh"]) + 0.3, field)
        height = plate * col(p["stipple_h"])
        feature = plate
    mottle = _sn(p, "c_mottle", size, 2.5, 1.0, 16.0)
    kd = _c(p, "colour") * _f(torch.exp(col(p["mottle"]) * mottle))
    rough = col(p["rough"]) * (1 + col(p["rough_var"]) * (feature.clamp(-2, 2) - 0.5))
    return Layers(height, kd, rough, _c(p, "ks"))


# ---- metals --------------------------------------------------------------------------------------


def _sample_brushed(d: Draw) -> tuple[str, dict]:
    p = dict(
        angle=d.pick([0.0, math.pi / 2, d.u(-math.pi, math.pi)]), aniso=d.u(20.0, 120.0),
        slope=d.logu(0.01, 0.15), rough=d.logu(0.06, 0.5), streak_rough=d.u(0.05, 0.4),
        smudge=d.u(0.0, 0.3), ks=_metal(d), kd=_metal_kd(d),
        c_streak=d.spectrum(F_DETAIL), c_smudge=d.spectrum(F_SHAPE),
    )
    return "streaks", p


def _build_brushed(p: dict, variant: str, size: int) -> Layers:
    streak = _sn(p, "c_streak", size, 1.0, 12.0, 128.0, angle=p["angle"], aniso=p["aniso"], unit="slope")
    sstd = streak / streak.std(dim=(1, 2), keepdim=True).clamp_min(1e-8)
    height = streak * col(p["slope"])
    smudge = smoothstep(0.0, 2.0, _sn(p, "c_smudge", size, 3.0, 1.0, 12.0)) * col(p["smudge"])
    rough = col(p["rough"]) * (1 + col(p["streak_rough"]) * sstd.clamp(-2.5, 2.5) / 2.5) + 0.3 * smudge
    ks = _c(p, "ks") * _f(1 - 0.3 * smudge)
    kd = _c(p, "kd") * _f(1 + 2 * smudge)
    return Layers(height, kd, rough, ks)


def _sample_hammered(d: Draw) -> tuple[str, dict]:
    p = dict(
        n=float(d.int(4, 16)), jitter=d.u(0.6, 1.0), slope=d.u(0.15, 0.9),
        fine_slope=d.logu(0.005, 0.08), rough=d.logu(0.03, 0.4), rough_var=d.u(0.0, 0.3),
        patina=d.p(0.3) * d.u(0.3, 1.0), patina_colour=d.pick([(0.08, 0.2, 0.14), (0.15, 0.08, 0.04), (0.05, 0.05, 0.05)]),
        ks=_metal(d), kd=_metal_kd(d), table=d.table(16, 2), cell_values=d.table(16, 2).reshape(256, 2),
        c_fine=d.spectrum(F_DETAIL), c_patina=d.spectrum(F_SHAPE),
    )
    return "cells", p


def _build_hammered(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["n"].device)
    c = cellular(x, y, p["n"], p["table"], p["jitter"])
    vals = lookup_flat(p["cell_values"], c["id"])
    r = 0.6 / col(p["n"])
    dent = col(p["slope"]) * (0.7 + 0.6 * vals[:, 0]) * c["f1"] ** 2 / (2 * r)
    fine = _sn(p, "c_fine", size, 1.5, 10.0, 128.0, unit="slope") * col(p["fine_slope"])
    height = dent + fine
    pat = smoothstep(-0.3, 1.0, _sn(p, "c_patina", size, 3.0, 1.0, 12.0)) * col(p["patina"])
    pat = pat * (1 - 0.6 * smoothstep(0.0, 1.0, c["f1"] / r))  # patina sits in the dents
    rough = col(p["rough"]) * (1 + col(p["rough_var"]) * (2 * vals[:, 1] - 1)) + 0.5 * pat
    ks = lerp(_c(p, "ks"), torch.full_like(_c(p, "ks"), 0.04), _f(pat))
    kd = lerp(_c(p, "kd"), _c(p, "patina_colour"), _f(pat))
    return Layers(height, kd, rough, ks)


# ---- scratches -----------------------------------------------------------------------------------

_N_SCRATCHES = 20


def _sample_scratched(d: Draw) -> tuple[str, dict]:
    metal = d.p(0.6)
    main = d.u(-math.pi, math.pi)
    spread = d.pick([0.15, 0.5, math.pi])
    count = d.int(5, _N_SCRATCHES)
    seg = torch.zeros(_N_SCRATCHES, 6)
    for k in range(_N_SCRATCHES):
        w = d.logu(0.0015, 0.005)
        seg[k] = torch.tensor([d.u(-0.1, 1.1), d.u(-0.1, 1.1), main + d.u(-spread, spread),
                               d.logu(0.05, 0.6), w, w * d.u(0.1, 0.6) * (k < count)])
    p = dict(
        seg=seg, hair_angle=main + d.u(-0.3, 0.3), hair_aniso=d.u(40.0, 150.0), hair=d.u(0.0, 1.0),
        hair_t=d.u(1.6, 2.6), base_slope=d.logu(0.003, 0.05),
        ks=_metal(d) if metal else _dielectric_ks(d, 0.035, 0.07),
        kd=_metal_kd(d) if metal else d.colour(PAINT, value=0.2),
        rough=d.logu(0.02, 0.3), scratch_rough=d.u(0.15, 0.5), scratch_light=0.0 if metal else d.u(0.0, 0.4),
        c_hair=d.spectrum(F_DETAIL), c_wear=d.spectrum(F_SHAPE), c_base=d.spectrum(F_DETAIL),
    )
    return "lines", p


def _build_scratched(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["seg"].device)
    dig = torch.zeros(p["seg"].shape[0], size, size, device=x.device)
    mark = torch.zeros_like(dig)
    for k in range(_N_SCRATCHES):
        s = p["seg"][:, k]
        cx, cy, a, half, w, depth = (col(s[:, i]) for i in range(6))
        dxn, dyn = torch.cos(a), torch.sin(a)
        rx, ry = x - cx, y - cy
        t = (rx * dxn + ry * dyn).clamp(-half, half)
        dist2 = (rx - t * dxn) ** 2 + (ry - t * dyn) ** 2
        taper = 1 - (t / half) ** 4
        prof = torch.exp(-dist2 / (w * w)) * taper
        dig = torch.maximum(dig, depth * prof)
        mark = torch.maximum(mark, prof * (depth > 0))
    hair_n = _sn(p, "c_hair", size, 0.0, 40.0, 160.0, angle=p["hair_angle"], aniso=p["hair_aniso"])
    wear = smoothstep(-0.5, 1.5, _sn(p, "c_wear", size, 3.0, 1.0, 12.0)) * col(p["hair"])
    hair = smoothstep(col(p["hair_t"]), col(p["hair_t"]) + 0.6, hair_n) * wear
    base = _sn(p, "c_base", size, 2.0, 2.0, 128.0, unit="slope") * col(p["base_slope"])
    height = base - dig - 0.0003 * hair
    m = torch.maximum(mark, 0.6 * hair)
    rough = col(p["rough"]) + col(p["scratch_rough"]) * m
    kd = _c(p, "kd") * _f(1 + col(p["scratch_light"]) * m)
    return Layers(height, kd, rough, _c(p, "ks"))


# ---- paint ---------------------------------------------------------------------------------------


def _sample_paint(d: Draw) -> tuple[str, dict]:
    if d.p(0.6):
        rust = d.p(0.6)
        p = dict(
            thresh=d.u(-1.2, 0.8), edge=d.u(0.02, 0.15), n=float(d.int(4, 16)), jitter=d.u(0.6, 1.0),
            crack=d.u(0.0, 0.003), thick=d.logu(0.001, 0.005), paint=d.colour(PAINT, value=0.15),
            paint_rough=d.u(0.15, 0.6), paint_ks=_dielectric_ks(d, 0.035, 0.06),
            sub_kd=d.colour(RUST) if rust else _metal_kd(d), sub_ks=_dielectric_ks(d, 0.02, 0.04) if rust else _metal(d),
            sub_rough=d.u(0.7, 1.0) if rust else d.u(0.25, 0.6), sub_slope=d.logu(0.05, 0.4),
            table=d.table(16, 2), c_mask=d.spectrum(F_SHAPE * 2), c_sub=d.spectrum(F_DETAIL),
            c_fine=d.spectrum(F_DETAIL),
        )
        return "peeling", p
    n = d.int(70, 128)
    colour = d.colour(PAINT, value=0.2)
    p = dict(
        n=float(n), tilt=d.u(0.1, 0.5), kd=tuple(c * d.u(0.2, 0.8) for c in colour),
        flake=tuple(min(1.0, 0.3 + 0.7 * c) for c in d.colour(PAINT + METAL, value=0.1)),
        flake_ks=d.u(0.2, 0.9), coat_ks=d.u(0.04, 0.07), rough=d.logu(0.05, 0.35), peel=d.logu(0.003, 0.03),
        table=d.table(128, 2), cell_values=d.table(128, 3).reshape(128 * 128, 3), c_peel=d.spectrum(F_SHAPE * 2),
    )
    return "flakes", p


def _build_paint(p: dict, variant: str, size: int) -> Layers:
    if variant == "peeling":
        x, y = grid(size, p["n"].device)
        mask_n = _sn(p, "c_mask", size, 2.5, 1.0, 40.0)
        mask = smoothstep(col(p["thresh"]) - col(p["edge"]), col(p["thresh"]) + col(p["edge"]), mask_n)
        c = cellular(x, y, p["n"], p["table"], p["jitter"])
        mask = mask * smoothstep(0.0, col(p["crack"]) + 1e-4, c["edge"] - col(p["crack"]) / 2)
        sub = _sn(p, "c_sub", size, 2.0, 4.0, 128.0, unit="slope") * col(p["sub_slope"])
        fine = _sn(p, "c_fine", size, 2.5, 8.0, 128.0, unit="slope") * 0.03
        height = sub + mask * (col(p["thick"]) + fine)
        m4 = _f(mask)
        subn = _f(_unit_std(sub)).clamp(-2, 2)
        kd = lerp(_c(p, "sub_kd") * (1 + 0.15 * subn), _c(p, "paint"), m4)
        rough = lerp(col(p["sub_rough"]), col(p["paint_rough"]), mask)
        ks = lerp(_c(p, "sub_ks"), _c(p, "paint_ks"), m4)
        return Layers(height, kd, rough, ks)
    x, y = grid(size, p["n"].device)
    c = cellular(x, y, p["n"], p["table"], torch.ones_like(p["n"]))
    vals = lookup_flat(p["cell_values"], c["id"])  # (B, 3, H, W): tilt angle, tilt size, sparkle
    a = 2 * math.pi * vals[:, 0]
    m = col(p["tilt"]) * vals[:, 1]
    slope = torch.stack([m * torch.cos(a), m * torch.sin(a)], 1)
    height = _sn(p, "c_peel", size, 3.0, 4.0, 40.0, unit="slope") * col(p["peel"])
    sparkle = _f(vals[:, 2] ** 2 * col(p["flake_ks"]))
    ks = lerp(torch.full_like(_c(p, "flake"), 1.0) * col(p["coat_ks"]).unsqueeze(1), _c(p, "flake"), sparkle)
    kd = _c(p, "kd") * (1 - 0.2 * sparkle)
    rough = col(p["rough"]) * (0.8 + 0.4 * vals[:, 1])
    return Layers(height, kd, rough, ks, slope=slope)


# ---- fabric --------------------------------------------------------------------------------------


def _sample_fabric(d: Draw) -> tuple[str, dict]:
    colour = d.colour(FABRIC, value=0.2)
    satin = d.p(0.2)
    p = dict(
        weave=float(d.pick([0, 0, 1, 2])), threads=float(d.int(12, 60)), angle=_angle(d, 0.8),
        width=d.u(0.7, 0.95), lift=d.u(0.2, 0.6), fibre=d.u(0.05, 0.3), fibre_aniso=d.u(8.0, 30.0),
        warp=colour, weft=colour if d.p(0.6) else d.colour(FABRIC, value=0.2), shade=d.u(0.2, 0.6),
        rough=d.u(0.25, 0.45) if satin else d.u(0.55, 1.0), rough_var=d.u(0.0, 0.2),
        ks=_dielectric_ks(d, 0.02, 0.05), c_fu=d.spectrum(F_DETAIL), c_fv=d.spectrum(F_DETAIL),
    )
    return "weave", p


def _build_fabric(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["threads"].device)
    xr, yr = rotate(x, y, p["angle"])
    n = col(p["threads"])
    u, v = xr * n, yr * n
    iu, iv = torch.floor(u), torch.floor(v)
    fu, fv = u - iu, v - iv
    weave = col(p["weave"])
    plain = torch.remainder(iu + iv, 2) < 1
    twill = torch.remainder(iu - iv, 3) < 1.5
    basket = torch.remainder(torch.floor(iu / 2) + torch.floor(iv / 2), 2) < 1
    warp_top = torch.where(weave < 0.5, plain, torch.where(weave < 1.5, twill, basket))
    w = col(p["width"])
    prof_u = torch.sqrt((1 - ((2 * fu - 1) / w) ** 2).clamp_min(0))  # warp thread runs along v
    prof_v = torch.sqrt((1 - ((2 * fv - 1) / w) ** 2).clamp_min(0))  # weft thread runs along u
    bend_v = torch.cos(math.pi * (fv - 0.5))  # a thread on top arches over the crossing
    bend_u = torch.cos(math.pi * (fu - 0.5))
    lift = col(p["lift"])
    fib_u = _sn(p, "c_fu", size, 0.5, 20.0, 128.0, angle=p["angle"], aniso=p["fibre_aniso"])
    fib_v = _sn(p, "c_fv", size, 0.5, 20.0, 128.0, angle=p["angle"] + math.pi / 2, aniso=p["fibre_aniso"])
    h_warp = prof_u * (1 + lift * torch.where(warp_top, bend_v, -bend_v)) + col(p["fibre"]) * fib_v
    h_weft = prof_v * (1 + lift * torch.where(warp_top, -bend_u, bend_u)) + col(p["fibre"]) * fib_u
    on_warp = h_warp >= h_weft
    hn = torch.maximum(h_warp, h_weft)
    height = hn * (0.25 / n) * 0.35
    kd = torch.where(_f(on_warp), _c(p, "warp"), _c(p, "weft"))
    occl = (hn / (1 + lift)).clamp(0, 1)
    kd = kd * _f(1 - col(p["shade"]) * (1 - occl)) * _f(torch.exp(0.1 * torch.where(on_warp, fib_v, fib_u)))
    rough = col(p["rough"]) * (1 + col(p["rough_var"]) * torch.where(on_warp, fib_v, fib_u).clamp(-2, 2) / 2) \
        + 0.2 * (1 - occl)
    return Layers(height, kd, rough, _c(p, "ks"))


# ---- noise mixtures ------------------------------------------------------------------------------


def _sample_mixture(d: Draw) -> tuple[str, dict]:
    variant = d.pick(["rust", "marble", "concrete", "plaster"])
    p = dict(
        thresh=d.u(-0.8, 0.8), edge=d.u(0.05, 0.4), beta=d.u(2.0, 3.2), fmin=d.u(1.0, 4.0), fmax=d.u(16.0, 64.0),
        veins=d.u(1.5, 5.0), turb=d.u(0.15, 0.6), vein_w=d.u(0.05, 0.3), angle=d.u(-math.pi, math.pi),
        pores=d.u(0.0, 1.0), pore_depth=d.u(0.0003, 0.0015), slope_a=d.logu(0.01, 0.3), slope_b=d.logu(0.05, 0.6),
        thick=d.u(0.0, 0.002),
        c_mask=d.spectrum(F_DETAIL // 2), c_a=d.spectrum(F_DETAIL), c_b=d.spectrum(F_DETAIL),
        c_pore=d.spectrum(F_DETAIL), c_turb=d.spectrum(F_SHAPE),
    )
    if variant == "rust":
        p.update(kd_a=_metal_kd(d), ks_a=d.colour(IRON, hue=0.03, value=0.08), rough_a=d.logu(0.05, 0.5),
                 kd_b=d.colour(RUST), ks_b=_dielectric_ks(d, 0.02, 0.04), rough_b=d.u(0.65, 1.0))
    elif variant == "marble":
        honed = d.p(0.3)
        p.update(kd_a=d.colour(STONE + [(0.9, 0.9, 0.88), (0.02, 0.02, 0.02), (0.15, 0.3, 0.2)], value=0.1),
                 ks_a=_dielectric_ks(d, 0.035, 0.06), rough_a=d.u(0.3, 0.5) if honed else d.logu(0.02, 0.12),
                 kd_b=d.colour(STONE + [(0.05, 0.05, 0.05), (0.9, 0.88, 0.85), (0.45, 0.3, 0.15)], value=0.2),
                 ks_b=_dielectric_ks(d, 0.035, 0.06), rough_b=d.u(0.3, 0.5) if honed else d.logu(0.02, 0.15))
    elif variant == "concrete":
        grey = d.u(0.25, 0.7)
        p.update(kd_a=d.colour([(grey, grey, grey * 0.95)], value=0.05), ks_a=_dielectric_ks(d, 0.02, 0.04),
                 rough_a=d.u(0.65, 1.0), kd_b=d.colour([(grey * 0.8, grey * 0.8, grey * 0.78)], value=0.15),
                 ks_b=_dielectric_ks(d, 0.02, 0.04), rough_b=d.u(0.6, 1.0))
    else:
        p.update(kd_a=d.colour(PAINT + STONE, value=0.15), ks_a=_dielectric_ks(d, 0.02, 0.06),
                 rough_a=d.u(0.3, 1.0), kd_b=d.colour(PAINT + SOIL, value=0.15), ks_b=_dielectric_ks(d, 0.02, 0.06),
                 rough_b=d.u(0.3, 1.0))
    return variant, p


def _build_mixture(p: dict, variant: str, size: int) -> Layers:
    x, y = grid(size, p["thresh"].device)
    mask_n = _sn(p, "c_mask", size, p["beta"], p["fmin"], p["fmax"])
    if variant == "marble":
        xr, _ = rotate(x, y, p["angle"])
        turb = _sn(p, "c_turb", size, 3.5, 1.0, 12.0) + 0.2 * mask_n
        s1 = torch.sin(math.pi * (col(p["veins"]) * xr + col(p["turb"]) * turb))
        s2 = torch.sin(math.pi * (2.7 * col(p["veins"]) * xr + 1.7 * col(p["turb"]) * turb + 0.4 * mask_n))
        mask = torch.maximum(1 - smoothstep(0.0, col(p["vein_w"]), s1.abs()),
                             0.5 * (1 - smoothstep(0.0, 0.5 * col(p["vein_w"]), s2.abs())))
    else:
        mask = smoothstep(col(p["thresh"]) - col(p["edge"]), col(p["thresh"]) + col(p["edge"]), mask_n)
    a = _sn(p, "c_a", size, 2.0, 3.0, 128.0, unit="slope")
    b = _sn(p, "c_b", size, 1.5, 6.0, 128.0, unit="slope")
    pore_n = _sn(p, "c_pore", size, 0.5, 30.0, 128.0)
    pores = smoothstep(1.8, 2.6, pore_n) * col(p["pores"]) * (variant in ("concrete", "plaster"))
    sa, sb = col(p["slope_a"]), col(p["slope_b"])
    if variant == "marble":
        sa, sb = sa * 0.1, sb * 0.1
    thick = col(p["thick"]) * (variant != "marble")
    height = lerp(a * sa, b * sb + thick, mask) - col(p["pore_depth"]) * pores
    m4 = _f(mask)
    an, bn = _f(_unit_std(a)), _f(_unit_std(b))
    kd = lerp(_c(p, "kd_a") * (1 + 0.08 * an.clamp(-2, 2)), _c(p, "kd_b") * (1 + 0.15 * bn.clamp(-2, 2)), m4)
    kd = kd * _f(1 - 0.5 * pores)
    rough = lerp(col(p["rough_a"]), col(p["rough_b"]), mask) + 0.2 * pores
    ks = lerp(_c(p, "ks_a"), _c(p, "ks_b"), m4)
    return Layers(height, kd, rough, ks)


# ---- registry ------------------------------------------------------------------------------------

_REGISTRY: dict[str, Family] = {f.name: f for f in [
    Family("tiles", _sample_tiles, _build_masonry),
    Family("bricks", _sample_bricks, _build_masonry),
    Family("planks", _sample_planks, _build_planks),
    Family("stones", _sample_stones, _build_stones),
    Family("leather", _sample_leather, _build_leather),
    Family("plastic", _sample_plastic, _build_plastic),
    Family("brushed_metal", _sample_brushed, _build_brushed),
    Family("hammered_metal", _sample_hammered, _build_hammered),
    Family("scratched", _sample_scratched, _build_scratched),
    Family("paint", _sample_paint, _build_paint),
    Family("fabric", _sample_fabric, _build_fabric),
    Family("mixture", _sample_mixture, _build_mixture),
]}

#: Names of the material families, in a fixed order.
FAMILIES: tuple[str, ...] = tuple(_REGISTRY)


# ---- heights to normals --------------------------------------------------------------------------


def height_to_normal(height: Tensor, slope: Tensor | None = None) -> Tensor:
    """Tangent-space unit normals from a height field by central finite differences.

    Args:
        height: (B, H, W) or (B, 1, H, W) heights in sample units (the sample side is 1, texel
            pitch 1/W across and 1/H down), row 0 at the top of the sample.
        slope: optional (B, 2, H, W) extra (dh/dx, dh/dy) added to the height's gradient.
    Returns:
        (B, 3, H, W) ``normalize(-dh/dx, -dh/dy, 1)`` with x to the right and y *up*: rows grow
        downwards, so ``dh/dy = (h[i-1] - h[i+1]) / (2 / H)`` inside, one-sided at the borders.
    """
    h = height.squeeze(1) if height.ndim == 4 else height
    H, W = h.shape[-2:]
    if H < 2 or W < 2:
        raise MaterialError(f"height_to_normal needs at least 2 x 2 texels, got {H} x {W}")
    (gx,) = torch.gradient(h, spacing=1.0 / W, dim=-1)
    (gy_down,) = torch.gradient(h, spacing=1.0 / H, dim=-2)
    gy = -gy_down
    if slope is not None:
        gx, gy = gx + slope[:, 0], gy + slope[:, 1]
    inv = torch.rsqrt(gx * gx + gy * gy + 1.0)  # (torch's vector_norm over dim 1 is slow on CPU)
    return torch.stack([-gx * inv, -gy * inv, inv], dim=1)


# ---- the generator -------------------------------------------------------------------------------


def _check_families(families: Sequence[str] | None) -> tuple[str, ...]:
    if families is None:
        return FAMILIES
    fams = tuple(families)
    unknown = [f for f in fams if f not in _REGISTRY]
    if unknown or not fams:
        raise MaterialError(f"unknown material families {unknown or '[] (empty)'}; available: {', '.join(FAMILIES)}")
    return fams


def family_of(index: int, seed: int = 0, families: Sequence[str] | None = None) -> str:
    """The family of material ``index`` in stream ``seed``.

    Families are dealt in shuffled rounds: every run of ``len(families)`` consecutive indices
    starting at a multiple of it holds each family exactly once, so small batches cover them all.
    """
    fams = _check_families(families)
    k, r = divmod(int(index), len(fams))
    g = torch.Generator().manual_seed(material_seed(seed, k, "families:" + ",".join(fams)))
    return fams[int(torch.randperm(len(fams), generator=g)[r])]


def sample_parameters(index: int, seed: int = 0, families: Sequence[str] | None = None) -> tuple[str, str, dict]:
    """``(family, variant, params)`` of material ``index``: every random choice it is built from."""
    fam = family_of(index, seed, families)
    d = Draw(material_seed(seed, index))
    variant, params = _REGISTRY[fam].sample(d)
    params["relief"] = d.logu(0.6, 1.6)
    if d.p(STEEP_FRACTION):
        params["relief"] *= d.logu(*STEEP_RELIEF)
    params["saturation"] = d.u(*SATURATION) if d.p(SATURATED_FRACTION) else 1.0
    return fam, variant, params


Bump = float | tuple[float, float]


def bump_factor(index: int, seed: int, bump: Bump) -> float:
    """Relief multiplier of material ``index`` of stream ``seed``: ``bump`` itself when it is a
    number, else log-uniform in the range ``(lo, hi)``, drawn from the material's own generator
    (salt ``"bump"``, so the material's other draws are the same for every ``bump``)."""
    if isinstance(bump, (int, float)):
        return float(bump)
    lo, hi = bump
    if lo == hi:
        return float(lo)
    return Draw(material_seed(seed, index, "bump")).logu(lo, hi)


def metal_dimming(index: int, seed: int, dark_metals: float) -> float:
    """F0 factor of the pure-metal texels (kd = 0) of material ``index``: with probability
    ``dark_metals`` log-uniform in :data:`DARK_METAL_F0`, else 1. Drawn from the material's own
    generator (salt ``"dark"``), so its other draws are the same for every ``dark_metals``, and
    ``dark_metals = 0`` leaves every stream as it was."""
    if dark_metals <= 0:
        return 1.0
    d = Draw(material_seed(seed, index, "dark"))
    return d.logu(*DARK_METAL_F0) if d.p(dark_metals) else 1.0


def pure_metal_texels(kd: Tensor) -> Tensor:
    """(B, 1, H, W) bool: the texels of diffuse albedo ``kd`` (B, 3, H, W) without any diffuse,
    the pure metal that ``dark_metals`` darkens."""
    return kd.amax(dim=1, keepdim=True) <= 0


def check_dark_metals(dark_metals: float) -> float:
    """``dark_metals`` validated: a probability in [0, 1]."""
    if isinstance(dark_metals, bool) or not isinstance(dark_metals, (int, float)) \
            or not 0.0 <= float(dark_metals) <= 1.0:
        raise MaterialError(f"dark_metals must be a fraction in [0, 1], got {dark_metals!r}")
    return float(dark_metals)


def check_bump(bump: Bump) -> Bump:
    """``bump`` validated: a finite number >= 0, or a range (lo, hi) with 0 < lo <= hi finite."""
    if isinstance(bump, bool):
        raise MaterialError(f"bump must be a number or a (lo, hi) range, got {bump!r}")
    if isinstance(bump, (int, float)):
        if not math.isfinite(bump) or bump < 0:
            raise MaterialError(f"bump must be a finite number >= 0, got {bump}")
        return float(bump)
    try:
        lo, hi = (float(v) for v in bump)
    except (TypeError, ValueError):
        raise MaterialError(f"bump must be a number or a (lo, hi) range, got {bump!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise MaterialError(f"a bump range (lo, hi) needs finite 0 < lo <= hi, got ({lo}, {hi})")
    return (lo, hi)


def _collate_params(items: list[dict], device) -> dict[str, Tensor]:
    out = {}
    for k in items[0]:
        vals = [it[k] for it in items]
        t = torch.stack(vals) if isinstance(vals[0], Tensor) else torch.tensor(vals, dtype=torch.float32)
        out[k] = t.to(device)
    return out


def _default_chunk(size: int, device: torch.device) -> int:
    budget = 1 << 22 if device.type == "cuda" else 1 << 19  # texels per build call
    return max(1, budget // (size * size))


def generate(n: int, size: int = 256, seed: int = 0, families: Sequence[str] | None = None,
             device: str | torch.device | None = None, *, start: int = 0, bump: Bump = 1.0,
             dark_metals: float = 0.0, chunk: int | None = None, threads: int | None = 1) -> SVBRDF:
    """Materials ``start .. start + n - 1`` of stream ``seed`` as one SVBRDF (B = n).

    Args:
        n: number of materials (>= 1).
        size: resolution, size x size texels (>= 4).
        seed: stream seed; material i of a stream is fixed (see the module docstring).
        families: restrict to these family names (default all of :data:`FAMILIES`); this changes
            which family each index gets, so it is part of the stream's identity.
        device: where the maps are built and returned (CPU default); random draws stay on the CPU.
        start: index of the first material.
        bump: multiplier of every height field (1 = the generator's own relief; 0 = flat), or a
            range ``(lo, hi)``: each material's own multiplier, log-uniform in it
            (:func:`bump_factor`). Training at 64 px uses (1, 4): a 64 px material lacks the
            finest, steepest detail of the same material at 256 px, and a multiplier of 2 restores
            the 256 px slope statistics (docs/benchmarks/data_statistics.md).
        dark_metals: fraction of materials whose pure-metal texels (kd = 0) have their F0 scaled
            by a factor log-uniform in :data:`DARK_METAL_F0` (:func:`metal_dimming`); materials
            without such texels are unchanged, and 0 (default) leaves the stream as it was.
        chunk: materials built per vectorised call (default: a cache-friendly size on CPU).
        threads: torch intra-op threads on the CPU while generating (restored afterwards); None
            keeps torch's setting. The build is many small tensor ops, so the default is one
            thread per process, with DataLoader workers for parallelism: measured 4x faster than
            two threads on a busy 2-core machine (docs/benchmarks/procedural_coverage.md).
    Returns:
        :class:`SVBRDF` with maps (n, C, size, size), ``name`` ``"procedural:seed:start"``.
    """
    if n < 1:
        raise MaterialError(f"generate needs n >= 1, got {n}")
    if size < 4:
        raise MaterialError(f"generate needs size >= 4, got {size}")
    return generate_indices(range(start, start + n), size, seed, families, device, bump=bump,
                            dark_metals=dark_metals, chunk=chunk, threads=threads, name=f"procedural:{seed}:{start}")


def generate_indices(indices: Sequence[int], size: int = 256, seed: int = 0,
                     families: Sequence[str] | None = None, device: str | torch.device | None = None, *,
                     bump: Bump = 1.0, dark_metals: float = 0.0, chunk: int | None = None,
                     threads: int | None = 1, name: str | None = None) -> SVBRDF:
    """Materials at arbitrary ``indices`` of stream ``seed`` (in that order), built in vectorised
    groups; arguments as for :func:`generate`."""
    dev = torch.device(device) if device is not None else torch.device("cpu")
    indices = [int(i) for i in indices]
    if not indices:
        raise MaterialError("generate_indices needs at least one index")
    if any(i < 0 for i in indices):
        raise MaterialError(f"material indices must be >= 0, got {min(indices)}")
    _check_families(families)
    bump = check_bump(bump)
    dark_metals = check_dark_metals(dark_metals)
    if size < 4:
        raise MaterialError(f"size must be >= 4, got {size}")
    chunk = chunk or _default_chunk(size, dev)
    previous = torch.get_num_threads()
    if threads is not None and dev.type == "cpu":
        torch.set_num_threads(max(1, int(threads)))
    try:
        return _build_all(indices, size, seed, families, dev, bump, dark_metals, chunk, name)
    finally:
        torch.set_num_threads(previous)


def _build_all(indices: list[int], size: int, seed: int, families, dev: torch.device, bump: Bump,
               dark_metals: float, chunk: int, name: str | None) -> SVBRDF:
    groups: dict[tuple[str, str], list[tuple[int, dict]]] = {}
    for pos, i in enumerate(indices):
        fam, variant, params = sample_parameters(i, seed, families)
        groups.setdefault((fam, variant), []).append(
            (pos, dict(params, bump=bump_factor(i, seed, bump), dimming=metal_dimming(i, seed, dark_metals))))
    B = len(indices)
    out = {"normal": torch.empty(B, 3, size, size, device=dev), "diffuse": torch.empty(B, 3, size, size, device=dev),
           "roughness": torch.empty(B, 1, size, size, device=dev), "specular": torch.empty(B, 3, size, size, device=dev)}
    with torch.no_grad():
        for (fam, variant), members in groups.items():
            for s in range(0, len(members), chunk):
                part = members[s:s + chunk]
                pos = torch.tensor([m[0] for m in part], device=dev)
                p = _collate_params([m[1] for m in part], dev)
                lay = _REGISTRY[fam].build(p, variant, size)
                maps = _finish(lay, p["relief"] * p["bump"], size, p["saturation"], p["dimming"])
                for k, v in maps.items():
                    out[k].index_copy_(0, pos, v)
    return SVBRDF(**out, name=name, check=False)


def _saturate(c: Tensor, saturation: Tensor) -> Tensor:
    """(B, 3, H, W) colours pushed away from their Rec. 709 luminance by (B,) factors (1: unchanged)."""
    lum = 0.2126 * c[:, 0:1] + 0.7152 * c[:, 1:2] + 0.0722 * c[:, 2:3]
    return lum + (c - lum) * saturation.view(-1, 1, 1, 1)


def _finish(lay: Layers, relief: Tensor, size: int, saturation: Tensor | None = None,
            dimming: Tensor | None = None) -> dict[str, Tensor]:
    """Layers -> clamped SVBRDF maps (normals from height x relief, colours saturated by
    ``saturation`` (B,) when given and not all 1, the F0 of texels without diffuse (pure metal)
    scaled by ``dimming`` (B,) when given and not all 1)."""
    B = relief.shape[0]
    shape = (B, 3, size, size)
    slope = None if lay.slope is None else lay.slope * relief.view(-1, 1, 1, 1)
    normal = height_to_normal(lay.height * col(relief), slope)
    rough = lay.rough.expand(B, size, size).unsqueeze(1)
    kd, ks = lay.kd.expand(shape), lay.ks.expand(shape)
    if saturation is not None and bool((saturation != 1).any()):
        kd, ks = _saturate(kd, saturation), _saturate(ks, saturation)
    if dimming is not None and bool((dimming != 1).any()):
        # after saturation, which keeps kd = 0 at 0
        ks = torch.where(pure_metal_texels(kd), ks * dimming.view(-1, 1, 1, 1), ks)
    return {"normal": normal, "diffuse": kd.clamp(0.0, 1.0),
            "roughness": rough.clamp(ROUGHNESS_MIN, 1.0), "specular": ks.clamp(0.0, 1.0)}


def material(index: int, size: int = 256, seed: int = 0, families: Sequence[str] | None = None,
             device: str | torch.device | None = None, *, bump: Bump = 1.0, dark_metals: float = 0.0) -> SVBRDF:
    """Material ``index`` of stream ``seed`` alone (B = 1); equal to ``generate(..)[index - start]``."""
    return generate(1, size, seed, families, device, start=index, bump=bump, dark_metals=dark_metals)
