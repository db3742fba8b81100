"""The closed-form part of the Mitsuba path's estimator: a control variate for Eq. 1 (torch side).

The ``importance`` integrator (plugins/importance_integrator.py) estimates

    I_p(x) = K_p(x) + integral over the LCD of [f(w) L_p(w) e(w) - g_p(w)] dw,
    K_p(x) = integral over the LCD of g_p(w) dw                                  (known exactly),

by Monte Carlo on the residual only; any g_p keeps the estimate unbiased, and the closer g_p is to
the integrand, the smaller the noise. This module computes g_p's coefficients per texel and K_p in
closed form; the plugin evaluates g_p pointwise from the same coefficients, so the two can never
disagree. Two terms (either may be switched off by the scene file's integrator options):

* diffuse: ``g_d = Lbar_{p,b(w)} e_b(x) kd (1 - ks) (n . w)^+ / pi``, the BRDF's own diffuse term
  under the pattern averaged over K x K blocks of cells b (``cv_blocks``), with the emission decay
  e_b(x) at each block's centre. Its integral is ``kd (1 - ks) sum_b Lbar_{p,b} n . Phi'_b(x)``
  with ``Phi'_b(x) = e_b(x) Phi_b(x)``, Phi_b the block's vector form factor (Lambert's formula;
  geometry only, computed once per rig, resolution and K). ``n . Phi_b`` is the block's form
  factor only while the whole LCD lies above the horizon of n; at texels where it does not, the
  diffuse term is left to Monte Carlo (weight 0).
* specular ("ltc"): ``g_s = c_p(x) S(x) D_ltc(w)``, the fitted LTC lobe (:mod:`.ltc_fit`, in the
  view frame of :func:`.ltc.view_frame`) under one radiance per texel and pattern, c_p the block
  radiance times decay where the lobe's peak direction M z meets the LCD (its centre when it
  points away), S = ks (A_1 - A_S) + A_S. Its integral is ``c_p S E(M^-1 LCD)``, the clipped form
  factor of the warped LCD (:mod:`.polygon`). Switched off below ``ltc_min_roughness`` (a
  near-mirror LTC lobe that misses the true one by a fraction of its width makes the residual
  spikier, not smoother) and where cos(theta_v) < ``ltc_min_cos_view`` (at grazing views the LTC
  overestimates the lobe's tail several-fold, and so large a g makes the residual larger than the
  integrand: the "tilt=70" column of docs/benchmarks/render_tradeoff.md).
* specular under every cell ("ltc-cells": replaces the term above where roughness >=
  ``ltc_cells_min_roughness``): one radiance per texel cannot follow a sparse pattern under a wide
  lobe (a rough metal under adaptive patterns is the worst case of the procedural study), so this
  term keeps each cell's own radiance and approximates only the lobe:
  ``g_s = S q(y) R_c(y) / G(y)`` for a direction that meets the LCD at y in cell c(y), where
  ``G = cos(theta_lcd) / r^2`` turns LCD area into solid angle, R_c is the cell's radiance with
  the decay's position factor at the cell's centre, and q is the bilinear interpolant, over a
  (k + 1) x (k + 1) grid of LCD points v (``ltc_grid`` = k), of
  ``q_v = D_ltc(w_v) G_v d_v`` (w_v the direction to v, d_v the decay's cosine factor there).
  A bilinear function's mean over a rectangle inside one grid quad is its value at the
  rectangle's centre, so the integral is exact and cheap:
  ``S sum_v q_v T_{p,v}``, ``T_{p,v} = sum_c t_v(c) R_{p,c} A_c`` with t_v(c) the bilinear
  weight of vertex v at cell c's centre: a fixed linear map of the pattern. The residual is then
  ``R_c(y) (f cos d(y) - S q(y) / G(y))`` (f cos the BRDF times the cosine, d(y) the decay's
  cosine factor; up to the position factor's change within a cell): the pattern factors out, and
  what is left is the LTC fit's and the interpolation's error, whatever the pattern. Below
  ``ltc_cells_min_roughness`` the lobe is too narrow for the grid and the one-radiance term
  stays. The diffuse lobe goes the same way
  in this mode (``q^d_v = (n . w_v)^+ / pi G_v d_v``, weight kd (1 - ks)) in place of the block
  term: block means miss a sparse pattern's detail under it as well, and any q keeps the
  integral exact, also where the LCD crosses the horizon of n.
* specular under the cells around a narrow lobe's peak ("ltc-cells" with ``ltc_window`` = w > 0:
  replaces the one-radiance term where ``ltc_window_min_roughness`` <= roughness <
  ``ltc_cells_min_roughness``): a lobe a cell or two wide is too narrow for the grid, and one
  radiance cannot follow the pattern's cell-to-cell changes under it (the step edges and random
  patterns of the roughness study). In the w x w cells around the point where the lobe's peak
  direction meets the LCD, ``g_s = S omega_c R_c D_ltc(w)``, omega_c the decay's cosine factor at
  cell c's centre (0 for a cell that crosses the warped horizon); 0 outside the window. Its
  integral ``S sum_c omega_c R_c E_c`` is exact: E_c, the LTC's integral over cell c, is the form
  factor of the cell warped by M^-1 (Lambert's formula, no clipping for a cell wholly above the
  warped horizon, i.e. all four corners above it; the half-plane the LTC is positive on is
  convex), and the w x w cells share their (w + 1)^2 warped corners and 2 w (w + 1) edges. The
  residual is then ``R_c (f cos d - S omega_c D_ltc)`` inside the window (the fit's error) and the
  tail ``f R cos d`` outside it.

* the per-cell terms in the integrator's kernels ("ltc-grid", the default): the per-cell
  specular term where roughness >= ``ltc_cells_min_roughness`` and the per-cell diffuse term
  everywhere, as in "ltc-cells", and with ``ltc_window`` = w > 0 the window term where
  ``ltc_window_min_roughness`` <= roughness < ``ltc_cells_min_roughness``, but without the
  one-radiance term around it (a wider lobe's tail outside the window is left to Monte Carlo) and
  with all of the per-texel work (the LTC lookup, S, the lobe grid q_v, q^d_v, the window's warped
  cells, K_p) done by the integrator, one lane per texel (plugins/importance_integrator.py,
  ``_GridControlVariate``; the window's w^2 cells in a loop, not unrolled, so its kernel compiles
  once whatever w). This module gives it only the patterns' grid radiance T_{p,v}
  (:attr:`ControlVariate.grid_radiance`, the fixed linear map of the pattern above), each cell's
  radiance for the window (:attr:`ControlVariate.cell_radiance`) and the LTC table. At 64 px,
  B = 4, "ltc-cells" spends about half of a 4-spp render in torch's closed form
  (docs/benchmarks/cv_cost.md): the per-texel work there is many small tensor operations, each a
  pass over memory, where one kernel does it in one pass. ``known`` is None: the integrator's
  result is the whole estimate. Its grid defaults to k = 4 (the kernel unrolls (k + 1)^2 lobe
  evaluations per texel; k = 8 leaves a third of its noise at roughness 0.3, 0.035 against 0.11
  at 4 spp, for 1.81x plain's time against 1.32x: docs/benchmarks/render_tradeoff_roughness_window.md,
  docs/benchmarks/cv_cost.md).

Rejected alternatives (tried during development, not kept as options): the closed form inside
the plugin, as one Dr.Jit kernel with the K x K block polygons unrolled, took the LLVM backend
seconds per block to compile, and a per-block contraction there cost more in gathers than the
whole render; torch does the contraction as one batched matrix product. A specular term resolved
per block (K^2 clipped LTC polygons per texel) would follow sparse patterns under wide lobes, but
costs K^2 times the one polygon per texel used here; the per-cell term ("ltc-cells") gets the
pattern's detail for the price of (k + 1)^2 lobe evaluations per texel instead. Choosing c_p as
the lobe-weighted mean of the block radiances instead of the radiance at the peak left the
procedural study's errors about where they were, so the simpler choice stays.

For narrow lobes (roughness 0.02-0.2, the window term), measured on the example material under
MonoGrad, random and step-edge patterns at 32 px and 4 spp (relative RMSE against the reference;
the one-radiance term alone: 0.17 at r = 0.05, 0.135 at 0.1, 0.16 at 0.15): looking the peak's
radiance up per cell instead of per 8 x 8 block changed nothing (0.14 against 0.135 at r = 0.1),
so the noise is the pattern's changes under the lobe, which the window resolves: w = 4 gives
0.026 / 0.052 / 0.11, w = 8 0.010 / 0.016 / 0.053. A window alone, without the one-radiance term
outside it, left the tails of the wider lobes to Monte Carlo (w = 8: 0.033 at r = 0.1, 0.11 at
0.15). Below roughness 0.02 the term makes it worse (0.18 against 0.13 at r = 0.01): the fitted
lobe misses the near-mirror one by a fraction of its width, and light samples see the difference
unweighted. A 16 x 16 window, even alone, was better still at r = 0.15 and 0.19 (0.020, 0.044)
but costs four times the 8 x 8 one's edges per texel.

Shapes: B materials, P patterns, texels in row-major (H, W) order. Everything is differentiable
w.r.t. patterns and maps (torch autograd), as the residual is on the plugin's side.

Most of the work (the LTC lookup, the lobe grid, the window's form factors, the warped LCD) depends
on the maps alone; the patterns enter through a few products at the end. A training step and an
acquisition render the same materials twice (I_0 under L_0, then the adaptive patterns), so the
maps' part of the last call is kept (:data:`LAST_MATERIALS`) and reused for the same map tensors,
unchanged in place, whenever they do not require gradients.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import torch
from torch import Tensor

from ..rig import Rig, per_texel
from .ltc import view_frame
from .ltc_fit import default_table
from .polygon import clipped_polygon_vector_form_factor, grid_cell_form_factors, polygon_vector_form_factor

@dataclass
class ControlVariate:
    """Per-texel coefficients of g_p for the plugin and its exact integral.

    Attributes:
        block_radiance: (B, P, 3, K * K) Lbar_{p,b}, block b = row * K + column (None in mode
            "ltc-grid", as ``texel`` and ``known``: its integrator computes what it needs).
        texel: (B, H * W, 4 + 3 + 3 P [+ 6 [+ 5 + w^2]]) per texel: the LTC's M^-1 entries
            (a, b, c, d), the diffuse weight kd (1 - ks) (0 where the diffuse term is off), c_p S
            for every pattern (0 where the one-radiance specular term is off) and, in mode
            "ltc-cells", S (0 where the per-cell specular term is off) and kd (1 - ks) (the
            per-cell diffuse weight); with a window (w = ``ltc_window`` > 0) then S (0 where the
            window term is off), the window's first cell row and column, and omega_c for its
            w x w cells, row-major.
        known: (B, P, 3, H, W) K_p(x); None in mode "ltc-grid", whose integrator computes it.
        lobe_grid: mode "ltc-cells": (B, H * W, 2, (k + 1)^2) q_v and q^d_v, vertices row-major;
            else None.
        grid_radiance: mode "ltc-grid": (B, (k + 1)^2, width) T_{p,v}, vertices row-major, a
            vertex's 3 P values (pattern-major, the three channels side by side) zero-padded to
            :func:`vertex_packet_width` (the integrator reads them as packet loads); else None.
        ltc_table: mode "ltc-grid": the LTC table (n, n, 6) (:attr:`.ltc_fit.LtcTable.grid`) for the
            integrator's own lookup; else None.
        cell_radiance: mode "ltc-grid" with a window: (B, P, h w, 3) each cell's radiance times the
            decay's position factor at its centre, cells row-major (for the window's part of K_p);
            else None.
    """

    block_radiance: Tensor | None
    texel: Tensor | None
    known: Tensor | None
    lobe_grid: Tensor | None = None
    grid_radiance: Tensor | None = None
    ltc_table: Tensor | None = None
    cell_radiance: Tensor | None = None


def _block_average(rad: Tensor, k: int) -> Tensor:
    """(..., 3, h, w) cell radiance -> (..., 3, k * k) block means."""
    h, w = rad.shape[-2:]
    if h % k or w % k:
        raise ValueError(f"cv_blocks = {k} does not divide the LCD's {h} x {w} cells")
    lead = rad.shape[:-2]
    return torch.nn.functional.avg_pool2d(rad.reshape(-1, 1, h, w), (h // k, w // k)).reshape(*lead, k * k)


def _block_uv(k: int, dtype=torch.float64) -> Tensor:
    """(k + 1, k + 1, 2) uv of the block grid's vertices (u along columns, v along rows)."""
    g = torch.arange(k + 1, dtype=dtype) / k
    v, u = torch.meshgrid(g, g, indexing="ij")
    return torch.stack([u, v], -1)


def _block_form_factors(rig: Rig, height: int, width: int, k: int) -> Tensor:
    """(3, H * W, K * K) Phi'_b(x) = e_b(x) Phi_b(x), world axes first, float32 (geometry only;
    computed in chunks of texels, the float64 corner vectors of all blocks would not fit at 256 px).
    Cached per rig; a window's are its rows of the whole grid's."""
    return per_texel(rig, (height, width), lambda r, res: _block_form_factors_of(r, *res, k), 1)


@lru_cache(maxsize=8)
def _block_form_factors_of(rig: Rig, height: int, width: int, k: int) -> Tensor:
    lcd = rig.lcd_geometry(dtype=torch.float64)
    verts = lcd.point(_block_uv(k))  # (k+1, k+1, 3)
    quads = torch.stack([verts[:-1, :-1], verts[:-1, 1:], verts[1:, 1:], verts[1:, :-1]], 2).reshape(-1, 4, 3)
    points = rig.surface_points((height, width)).double().reshape(-1, 3)
    uv = (_block_uv(k)[:-1, :-1] + 0.5 / k).reshape(-1, 2)
    out = []
    for x in points.split(4096):
        rel = quads[None] - x[:, None, None]  # (n, K^2, 4, 3)
        phi = polygon_vector_form_factor(rel)
        centre = rel.mean(2)
        phi = phi * torch.sign((phi * centre).sum(-1, keepdim=True))  # towards the block
        cos_emit = (torch.nn.functional.normalize(-centre, dim=-1) @ lcd.normal)
        decay = rig.display.decay(uv.expand(x.shape[0], -1, -1), cos_emit)
        out.append(phi if decay is None else phi * decay[..., None])
    return torch.cat(out).permute(2, 0, 1).float().contiguous()


def _grid_geometry(rig: Rig, height: int, width: int, k: int) -> tuple[Tensor, Tensor]:
    """Per texel x and LCD grid vertex v (geometry only, float32): (N, 3, V) the unit world
    direction to v (world axes on the middle axis, for batched products), and (N, V)
    G_v d_v = cos(theta_lcd) / r^2 times the decay's cosine factor (0 where v does not face x);
    V = (k + 1)^2, vertices row-major. Cached per rig; a window's are its rows of the whole grid's."""
    return per_texel(rig, (height, width), lambda r, res: _grid_geometry_of(r, *res, k), 0)


@lru_cache(maxsize=8)
def _grid_geometry_of(rig: Rig, height: int, width: int, k: int) -> tuple[Tensor, Tensor]:
    lcd = rig.lcd_geometry(dtype=torch.float64)
    uv = _block_uv(k).reshape(-1, 2)
    x = rig.surface_points((height, width)).double().reshape(-1, 3)
    rel = lcd.point(uv)[None] - x[:, None]  # (N, V, 3)
    dist2 = rel.square().sum(-1)
    d = rel / dist2.sqrt()[..., None]
    cos_emit = -(d @ lcd.normal)
    g = cos_emit.clamp_min(0.0) / dist2
    decay = rig.display.decay(torch.full_like(uv, 0.5), cos_emit)  # at the centre: the cosine factor alone
    g = g if decay is None else g * decay
    return d.transpose(1, 2).float().contiguous(), g.float()


def _tent_weights(cells: int, k: int, dtype=torch.float64) -> Tensor:
    """(k + 1, cells) t_v(c) along one axis: the linear-interpolation weight of grid vertex v at
    the centre of cell c (k must divide cells, so every cell lies inside one grid interval)."""
    if cells % k:
        raise ValueError(f"ltc_grid = {k} does not divide the LCD's {cells} cells")
    t = (torch.arange(cells, dtype=dtype) + 0.5) / cells * k
    i = t.floor().clamp(0, k - 1)
    f = t - i
    w = torch.zeros(k + 1, cells, dtype=dtype)
    w[i.long(), torch.arange(cells)] = 1 - f
    w[i.long() + 1, torch.arange(cells)] += f
    return w


#: Elements of the (B, texels, 4, V) products that one chunk of :func:`_lobe_grid` holds: the
#: chunk's temporaries then stay in cache (one pass over all texels at 64 px, B = 4, k = 16 moves
#: ~80 MB per temporary, and took twice as long).
CHUNK_ELEMENTS = 2 ** 20


def _lobe_grid(rig: Rig, H: int, W: int, k: int, frame: Tensor, m_inv: Tensor, n: Tensor) -> Tensor:
    """For B N texels (frame and M^-1 (B N, 3, 3), normals n (B, N, 3), materials outermost): the
    lobe values (B, N, 2, V) at the grid vertices, q_v then q^d_v."""
    d, g = (t.to(frame.device, frame.dtype) for t in _grid_geometry(rig, H, W, k))
    N, V = g.shape
    B = frame.shape[0] // N
    # One batched product per texel position gives M^-1 w (rows 0-2: M^-1 times the view frame)
    # and n . w (row 3) for all B materials: (N, 4 B, 3) @ (N, 3, V). Broadcasting the grid's
    # directions over the materials instead copied them B times; with that copy and the chunks'
    # concatenation this function took about 1.4x as long (64 px, B = 4, k = 16, one thread).
    rows = torch.cat([m_inv @ frame, n.reshape(-1, 1, 3)], 1).reshape(B, N, 4, 3).transpose(0, 1).reshape(N, 4 * B, 3)
    det = (torch.linalg.det(m_inv).abs() / torch.pi).reshape(B, N).T  # (N, B)
    step = max(1, CHUNK_ELEMENTS // (4 * B * V))
    # Without gradients each chunk goes straight into the result; with them the chunks are
    # concatenated, since slice assignments' backward copies the whole buffer per chunk.
    out = None if torch.is_grad_enabled() and (rows.requires_grad or det.requires_grad) else \
        torch.empty(B, N, 2, V, dtype=frame.dtype, device=frame.device)
    chunks = []
    for i in range(0, N, step):
        j = min(N, i + step)
        wl = torch.bmm(rows[i:j], d[i:j]).view(j - i, B, 4, V)
        x, y, z = wl[:, :, 0], wl[:, :, 1], wl[:, :, 2]
        len2 = (x * x).addcmul_(y, y).addcmul_(z, z).clamp_min_(1e-24)
        gc = g[i:j, None]
        q = z.clamp_min(0.0) * (det[i:j, :, None] * gc) / len2.square_()  # (n, B, V)
        qd = wl[:, :, 3].clamp_min(0.0) * (gc / torch.pi)
        if out is None:
            chunks.append(torch.stack([q, qd], 2))
        else:
            out[:, i:j, 0] = q.transpose(0, 1)
            out[:, i:j, 1] = qd.transpose(0, 1)
    return out if out is not None else torch.cat(chunks).transpose(0, 1).contiguous()


def _grid_radiance(rig: Rig, k: int, rad: Tensor) -> Tensor:
    """T_{p,v} (B, P, 3, V) of the cell radiance ``rad`` (B, P, 3, h, w) without decay."""
    tv, tu, scale = (t.to(rad.device, rad.dtype) for t in _cell_weights(rig, k))
    return (tv @ (rad * scale) @ tu.T).flatten(-2)  # (B, P, 3, (k + 1)^2)


def _vertex_radiance(rig: Rig, k: int, rad: Tensor) -> Tensor:
    """T_{p,v} per vertex, (B, V, 3 P): the P patterns' three channels of a vertex side by side."""
    B, P = rad.shape[:2]
    return _grid_radiance(rig, k, rad).reshape(B, P * 3, -1).transpose(1, 2)


def vertex_packet_width(count: int) -> int:
    """The entries per vertex of :attr:`ControlVariate.grid_radiance`: 3 P rounded up to a power of
    two, so that the integrator reads a vertex's radiance as packet loads."""
    return 1 << (3 * count - 1).bit_length()


@lru_cache(maxsize=8)
def _position_factor(rig: Rig) -> Tensor:
    """(h, w) the decay's position factor at each cell's centre (ones without decay), float64."""
    h, w = rig.lcd_cells
    cell_uv = torch.stack(torch.meshgrid((torch.arange(w, dtype=torch.float64) + 0.5) / w,
                                         (torch.arange(h, dtype=torch.float64) + 0.5) / h, indexing="xy"), -1)
    position = rig.display.decay(cell_uv, torch.ones(h, w, dtype=torch.float64))
    return torch.ones(h, w, dtype=torch.float64) if position is None else position


@lru_cache(maxsize=8)
def _cell_weights(rig: Rig, k: int) -> tuple[Tensor, Tensor, Tensor]:
    """The fixed linear map of a pattern onto the grid (geometry only, float64): the tent weights
    t_v(c) along rows (k + 1, h) and columns (k + 1, w), and (h, w) each cell's area times the
    decay's position factor at its centre."""
    h, w = rig.lcd_cells
    scale = rig.lcd_geometry(dtype=torch.float64).area / (h * w) * _position_factor(rig)
    return _tent_weights(h, k), _tent_weights(w, k), scale


@dataclass
class _LobeWindow:
    """The window term's material part at texels ``idx`` (n,) of the B N: each window's row in
    the table of w x w patches of its material's cells (n,) (:func:`_window_integral`), its first
    cell row and column (n, 2), omega_c (n, w^2), omega_c E_c (n, w^2), the LTC's integral over the
    whole window (n,), horizon-clipped (what the one-radiance term leaves out; 0 where that term
    is off), and S there (n, 3)."""

    idx: Tensor
    patch: Tensor
    origin: Tensor
    omega: Tensor
    weight: Tensor
    outer: Tensor
    s: Tensor


def _check_window(rig: Rig, w: int) -> None:
    """Raises ValueError unless a w x w window fits on the rig's LCD."""
    h, wc = rig.lcd_cells
    if not 1 <= w <= min(h, wc):
        raise ValueError(f"ltc_window = {w} must lie in [1, {min(h, wc)}] (the LCD has {h} x {wc} cells)")


def _lobe_window(rig: Rig, w: int, frame: Tensor, m_inv: Tensor, x: Tensor, peak_uv: Tensor,
                 where: Tensor, one_radiance: Tensor, s: Tensor) -> _LobeWindow:
    """The window term's material part (module docstring) where ``where`` (B N,) is true: frames
    and M^-1 (B N, 3, 3), texel positions ``x`` (N, 3), ``peak_uv`` (B N, 2) where the lobe's peak
    meets the LCD, ``one_radiance`` (B N,) where the one-radiance term is on, S (B N, 3). In chunks
    of texels, as :func:`_lobe_grid` (at 128 px and w = 8 in one pass it took three times as long)."""
    _check_window(rig, w)
    idx = where.nonzero().squeeze(1)
    dev, dt = frame.device, frame.dtype
    step = max(1, CHUNK_ELEMENTS // (3 * (w + 1) ** 2))
    parts = [_window_chunk(rig, w, frame, m_inv, x, peak_uv, idx[i:i + step], one_radiance)
             for i in range(0, idx.numel(), step)]
    if not parts:
        return _LobeWindow(idx, torch.zeros(0, dtype=torch.long, device=dev), torch.zeros(0, 2, dtype=dt, device=dev),
                           *(torch.zeros(0, w * w, dtype=dt, device=dev) for _ in range(2)),
                           torch.zeros(0, dtype=dt, device=dev), s[idx])
    return _LobeWindow(idx, *(torch.cat(t) for t in zip(*parts)), s[idx])


def _window_chunk(rig: Rig, w: int, frame: Tensor, m_inv: Tensor, x: Tensor, peak_uv: Tensor,
                  idx: Tensor, one_radiance: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """:func:`_lobe_window`'s patch, origin, omega, weight and outer at texels ``idx`` (n,)."""
    h, wc = rig.lcd_cells
    n, N = idx.numel(), x.shape[0]
    dev, dt = frame.device, frame.dtype
    uv = peak_uv[idx].detach()  # the window's place is piecewise constant in the maps
    # Centred on the peak, inside the LCD: rows from v, columns from u.
    row0 = (uv[:, 1] * h - w / 2).round().clamp(0, h - w)
    col0 = (uv[:, 0] * wc - w / 2).round().clamp(0, wc - w)
    steps = torch.arange(w + 1, dtype=dt, device=dev)
    lcd = rig.lcd_geometry(dev, dt)
    xs = x[idx % N]
    c0, cu, cv = _warped_lcd(lcd, frame[idx], m_inv[idx], xs)  # corner (a, b) is c0 + u_b cu + v_a cv
    u = (col0[:, None] + steps) / wc  # (n, w + 1)
    v = (row0[:, None] + steps) / h
    warped = (c0[:, None, None] + u[:, None, :, None] * cu[:, None, None]
              + v[:, :, None, None] * cv[:, None, None])  # (n, w + 1, w + 1, 3)
    e = grid_cell_form_factors(warped)  # (n, w, w): E_c where the cell is above the warped horizon
    up = warped[..., 2] > 0
    whole = up[:, :-1, :-1] & up[:, :-1, 1:] & up[:, 1:, :-1] & up[:, 1:, 1:]  # above the warped horizon
    omega = whole.to(dt)
    if rig.display.has_decay:  # times the decay's cosine factor at each cell's centre
        uc, vc = (u[:, :-1] + u[:, 1:]) / 2, (v[:, :-1] + v[:, 1:]) / 2
        centre = (lcd.origin + uc[:, None, :, None] * lcd.edge_u + vc[:, :, None, None] * lcd.edge_v)
        to_x = torch.nn.functional.normalize(xs[:, None, None] - centre, dim=-1)
        cos_emit = to_x @ lcd.normal
        omega = omega * rig.display.decay(torch.full((*cos_emit.shape, 2), 0.5, dtype=dt, device=dev), cos_emit)
    omega = omega.reshape(n, -1)
    places = (h - w + 1) * (wc - w + 1)
    patch = (idx // N) * places + row0.long() * (wc - w + 1) + col0.long()
    # the window's clipped rim only where the one-radiance term needs it (roughness >= ltc_min_roughness)
    rim = torch.stack([warped[:, 0, 0], warped[:, 0, -1], warped[:, -1, -1], warped[:, -1, 0]], 1)
    needed = one_radiance[idx].nonzero().squeeze(1)
    outer = torch.zeros(n, dtype=dt, device=dev).index_put(
        (needed,), clipped_polygon_vector_form_factor(rim[needed])[:, 2].abs())
    return patch, torch.stack([row0, col0], -1), omega, omega * e.reshape(n, -1), outer


def _window_integral(rig: Rig, win: _LobeWindow, w: int, rad: Tensor) -> Tensor:
    """sum_c omega_c E_c R_c (n, P, 3) without S at the window's texels, for the cell radiance
    ``rad`` (B, P, 3, h, w) without decay."""
    h, wc = rig.lcd_cells
    B, P = rad.shape[:2]
    # Every w x w patch of each material's cell radiance, one row per window position: a texel
    # gathers one contiguous row instead of w^2 scattered cells.
    lit = rad.reshape(B, P * 3, h, wc) * _position_factor(rig).to(rad.device, rad.dtype)
    patches = torch.nn.functional.unfold(lit, w).transpose(1, 2).reshape(-1, P * 3, w * w)  # (B places, 3 P, w^2)
    step = max(1, CHUNK_ELEMENTS // (3 * P * w * w))
    parts = [torch.bmm(patches[win.patch[i:i + step]], win.weight[i:i + step, :, None])
             for i in range(0, win.idx.numel(), step)]
    return torch.cat(parts).reshape(-1, P, 3) if parts else rad.new_zeros(0, P, 3)


def _warped_lcd(lcd, frame: Tensor, m_inv: Tensor, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The LCD's points ``lcd.point(u, v)`` seen from texels ``x`` (n, 3) in their LTC's frame,
    warped by M^-1 (frames, M^-1 (n, 3, 3)): affine in (u, v), c0 + u cu + v cv, and (c0, cu, cv)
    (n, 3) each. With A = M^-1 F (F the view frame): c0 = A (origin - x), cu = A e_u, cv = A e_v."""
    # bmm of 3 x 3 matrices: 3-5x faster here than broadcast products and sums (n = 16k, one thread)
    base = torch.stack([lcd.origin - x, lcd.edge_u.expand_as(x), lcd.edge_v.expand_as(x)], -1)  # columns
    return ((m_inv @ frame) @ base).unbind(-1)


def _warped_lcd_form_factor(lcd, frame: Tensor, m_inv: Tensor, x: Tensor, where: Tensor) -> Tensor:
    """E(M^-1 LCD) (B N,): the clipped form factor of the LCD warped into each texel's LTC frame
    (frame, M^-1 (B N, 3, 3); texel positions ``x`` (N, 3)), computed only where ``where`` (B N,)
    is true and 0 elsewhere (one clipped polygon per texel is most of the one-radiance term's
    cost, and the per-cell term makes it unused at most texels)."""
    idx = where.nonzero().squeeze(1)
    e = torch.zeros(where.shape[0], dtype=frame.dtype, device=frame.device)
    if idx.numel() == 0:
        return e
    c0, cu, cv = _warped_lcd(lcd, frame[idx], m_inv[idx], x[idx % x.shape[0]])
    warped = torch.stack([c0, c0 + cu, c0 + cu + cv, c0 + cv], 1)  # the LCD's corners c0..c3
    return e.index_put((idx,), clipped_polygon_vector_form_factor(warped)[:, 2].abs())


def _peak_uv(rig: Rig, x: Tensor, d: Tensor) -> Tensor:
    """(N, 2) LCD uv where rays x + t d (world, N x 3) meet the LCD (its centre, 0.5, when they
    point away from it)."""
    uv, _, front = rig.lcd_geometry(x.device, x.dtype).hit(x, d)
    return torch.where(front[:, None], uv, torch.full_like(uv, 0.5))


def _peak_block(rig: Rig, uv: Tensor, x: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """Block index (N,) of LCD points ``uv`` (N, 2), and the decay factor of that block's centre
    towards the points x (world, N x 3) (N,)."""
    lcd = rig.lcd_geometry(x.device, x.dtype)
    ij = (uv * k).floor().clamp(0, k - 1)
    block = (ij[:, 1] * k + ij[:, 0]).long()
    centre_uv = (ij + 0.5) / k
    to_x = torch.nn.functional.normalize(x - lcd.point(centre_uv), dim=-1)
    decay = rig.display.decay(centre_uv, to_x @ lcd.normal)
    return block, (torch.ones_like(uv[:, 0]) if decay is None else decay)


MODES = ("diffuse", "ltc", "ltc-cells", "ltc-grid")


@dataclass
class _MaterialTerms:
    """The part of the control variate that depends on the materials and not on the patterns
    (:func:`_material_terms`), for B materials of N texels.

    Attributes:
        kdd: (B, N, 3) the block diffuse term's weight kd (1 - ks) (0 where it is off).
        block_ff: (B, N, K^2) n . Phi'_b for the block diffuse term (None in mode "ltc-cells").
        m_entries: (B, N, 4) the LTC's M^-1 entries.
        block: (B N,) the peak block of each texel, offset by its material's K^2 blocks (None in
            mode "diffuse").
        spec_weight: (B N, 3) S times the peak block's decay where the one-radiance term is on,
            else 0 (None in mode "diffuse").
        spec_ff: (B N,) E(M^-1 LCD), less the window's part where a window runs.
        lobe_grid: (B, N, 2, V) mode "ltc-cells": q_v, q^d_v; else None.
        s_cells, kd_cells: (B, N, 3) the per-cell terms' weights (mode "ltc-cells").
        window: the window term's material part (None without one).
        extra: the per-texel floats after c_p S in :attr:`ControlVariate.texel`.
    """

    kdd: Tensor
    m_entries: Tensor
    block_ff: Tensor | None = None
    block: Tensor | None = None
    spec_weight: Tensor | None = None
    spec_ff: Tensor | None = None
    lobe_grid: Tensor | None = None
    s_cells: Tensor | None = None
    kd_cells: Tensor | None = None
    window: _LobeWindow | None = None
    extra: list = field(default_factory=list)


def _material_terms(svbrdf, rig: Rig, mode: str, blocks: int, ltc_min_roughness: float, ltc_min_cos_view: float,
                    ltc_grid: int, ltc_cells_min_roughness: float, ltc_window: int,
                    ltc_window_min_roughness: float) -> _MaterialTerms:
    """:class:`_MaterialTerms` of ``svbrdf`` (the options as :func:`control_variate`'s)."""
    B = svbrdf.batch_size
    H, W = svbrdf.resolution
    N = H * W
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    n = torch.nn.functional.normalize(svbrdf.normal.reshape(B, 3, -1).transpose(1, 2), dim=-1)  # (B, N, 3)
    kd = svbrdf.diffuse.reshape(B, 3, -1).transpose(1, 2)
    ks = svbrdf.specular.reshape(B, 3, -1).transpose(1, 2)
    r = svbrdf.roughness.reshape(B, -1)
    x = rig.surface_points((H, W), dev).reshape(-1, 3).to(dt)
    wo = rig.view_directions((H, W), dev).reshape(-1, 3).to(dt)
    corners = rig.lcd_corners.to(dev, dt)
    cos_v = (n * wo).sum(-1)  # (B, N)
    ok = (cos_v > 0) & (wo[:, 2] > 0)
    # (Broadcast products below, not einsum: einsum lowers these to bmm over 10^4 tiny matrices.)
    if mode == "ltc-cells":  # the diffuse lobe goes per cell (below)
        terms = _MaterialTerms(kdd=torch.zeros_like(kd), m_entries=torch.zeros(B, N, 4, dtype=dt, device=dev))
    else:
        above = ((n[:, None] * (corners[:, None] - x[None])[None]).sum(-1) > 0).all(1)
        kdd = torch.where((ok & above)[..., None], kd * (1 - ks), torch.zeros_like(kd))  # (B, N, 3)
        phi = _block_form_factors(rig, H, W, blocks).to(dev, dt)  # (3, N, K^2)
        ff = n[:, :, 0:1] * phi[0]  # n . Phi_b: (B, N, K^2), one temporary
        ff.addcmul_(n[:, :, 1:2], phi[1]).addcmul_(n[:, :, 2:3], phi[2])
        terms = _MaterialTerms(kdd=kdd, m_entries=torch.zeros(B, N, 4, dtype=dt, device=dev), block_ff=ff)
    if mode == "diffuse":
        return terms
    nf, wf = n.reshape(-1, 3), wo.repeat(B, 1)  # (B N, 3), materials outermost
    frame, _ = view_frame(nf, wf)
    m_inv, a_one, a_s = default_table().lookup(r.reshape(-1), cos_v.reshape(-1))
    a, bb, c, d = m_inv[:, 0, 0], m_inv[:, 0, 2], m_inv[:, 1, 1], m_inv[:, 2, 0]
    terms.m_entries = torch.stack([a, bb, c, d], -1).reshape(B, N, 4)
    # The lobe's peak direction M z: for M^-1 = [[a, 0, b], [0, c, 0], [d, 0, 1]], along (-b, 0, a)/(a - b d).
    peak = torch.nn.functional.normalize(torch.stack([-bb, torch.zeros_like(a), a], -1)
                                         * torch.sign(a - bb * d)[:, None], dim=-1)
    xb = x.repeat(B, 1)
    peak_uv = _peak_uv(rig, xb, (frame * peak[..., None]).sum(1))
    block, decay = _peak_block(rig, peak_uv, xb, blocks)
    terms.block = torch.arange(B, device=dev).repeat_interleave(N) * blocks * blocks + block
    fits = ok.reshape(-1) & (cos_v.reshape(-1) >= ltc_min_cos_view)
    use = fits & (r.reshape(-1) >= ltc_min_roughness)
    s_all = ks.reshape(-1, 3) * (a_one - a_s)[:, None] + a_s[:, None]
    s = torch.where(use[:, None], s_all, 0.0)
    window_ff = None
    if mode == "ltc-cells":
        cells = (use & (r.reshape(-1) >= ltc_cells_min_roughness))[:, None]
        terms.s_cells, s = torch.where(cells, s, 0.0).reshape(B, N, 3), torch.where(cells, 0.0, s)
        terms.kd_cells = torch.where(ok[..., None], kd * (1 - ks), torch.zeros_like(kd))
        terms.lobe_grid = _lobe_grid(rig, H, W, ltc_grid, frame, m_inv, n)  # (B, N, 2, V)
        terms.extra = [terms.s_cells, terms.kd_cells]
        use = use & ~cells[:, 0]  # where the one-radiance term is left
        if ltc_window:
            win = fits & (r.reshape(-1) >= ltc_window_min_roughness) & ~cells[:, 0]
            s_win = torch.where(win[:, None], s_all, 0.0)
            lw = _lobe_window(rig, ltc_window, frame, m_inv, x, peak_uv, win, use, s_win)
            # Texels without a window get one off the LCD, so that no direction falls in it.
            off = torch.cat([torch.full((B * N, 2), -float(max(rig.lcd_cells)), dtype=dt, device=dev),
                             torch.zeros(B * N, ltc_window ** 2, dtype=dt, device=dev)], -1)
            placed = off.index_put((lw.idx,), torch.cat([lw.origin, lw.omega], -1))
            terms.extra += [s_win.reshape(B, N, 3), placed.reshape(B, N, -1)]
            terms.window = lw
            # the one-radiance term stays where it is on, outside the window
            window_ff = torch.zeros(B * N, dtype=dt, device=dev).index_put((lw.idx,), lw.outer)
    e = _warped_lcd_form_factor(rig.lcd_geometry(dev, dt), frame, m_inv, x, use)
    terms.spec_ff = e if window_ff is None else e - window_ff  # both 0 where the one-radiance term is off
    terms.spec_weight = s * decay[:, None]
    return terms


def _maps(svbrdf) -> tuple[Tensor, ...]:
    return svbrdf.normal, svbrdf.diffuse, svbrdf.roughness, svbrdf.specular


def _maps_version(svbrdf) -> tuple | None:
    """The identity and in-place version of the four maps, or None where the terms of this call
    must not outlive it (maps that require gradients need this call's graph; inference tensors
    have no version counter)."""
    maps = _maps(svbrdf)
    if any(m.requires_grad or m.is_inference() for m in maps):
        return None
    return tuple((id(m), m._version) for m in maps)


class _LastMaterials:
    """The material terms of the last material batch rendered: a training step and an acquisition
    render the same materials twice (I_0 under L_0, then the adaptive patterns), and the terms do
    not depend on the patterns. One entry; it keeps its maps alive, so that their ids stay theirs;
    reused only for the same map tensors, unchanged in place (their version counters), with the
    same rig and options."""

    def __init__(self):
        self.clear()

    def clear(self) -> None:
        self.key, self.maps, self.terms, self.hits = None, None, None, 0

    def terms_for(self, svbrdf, rig: Rig, options: tuple, compute) -> _MaterialTerms:
        version = _maps_version(svbrdf)
        if version is None:
            return compute()
        key = (rig, options, version)
        if self.terms is not None and self.key == key:
            self.hits += 1
            return self.terms
        self.clear()  # the old entry's memory first: at 256 px its lobe grid is ~150 MB a material
        self.terms = compute()
        self.key, self.maps = key, _maps(svbrdf)
        return self.terms


#: The material terms of the last materials rendered (:class:`_LastMaterials`).
LAST_MATERIALS = _LastMaterials()


def control_variate(svbrdf, patterns: Tensor, rig: Rig, *, mode: str = "ltc-cells", blocks: int = 8,
                    ltc_min_roughness: float = 0.1, ltc_min_cos_view: float = 0.1, ltc_grid: int = 16,
                    ltc_cells_min_roughness: float = 0.2, ltc_window: int = 8,
                    ltc_window_min_roughness: float = 0.02) -> ControlVariate:
    """The control variate of B materials under P patterns ((P, 3, h, w) or (B, P, 3, h, w)).

    ``mode``: "diffuse", "ltc" (diffuse + specular under one radiance per texel) or "ltc-cells"
    (that, with the specular lobe under every cell's radiance where roughness >=
    ``ltc_cells_min_roughness``, on a ``ltc_grid`` grid, and with ``ltc_window`` > 0 under the
    cells of a window around the peak of narrower lobes down to ``ltc_window_min_roughness``);
    ``blocks``: K; "ltc-grid" (the per-cell terms alone, ``known`` left to the integrator's
    kernel); see the module docstring. What depends on the materials alone is reused from
    the last call with the same maps (:data:`LAST_MATERIALS`), so a second set of patterns on the
    same materials costs only the patterns' part.
    """
    if mode not in MODES:
        raise ValueError(f"control variate mode must be one of {', '.join(MODES)}, got {mode!r}")
    B = svbrdf.batch_size
    H, W = svbrdf.resolution
    N = H * W
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    h, w = rig.lcd_cells
    P = patterns.shape[-4]
    rad = rig.material_radiance(patterns, B, dev, dt).reshape(B, P, 3, h, w)
    if mode == "ltc-grid":  # the rest is the integrator's
        cells = None
        if ltc_window:
            _check_window(rig, ltc_window)
            cells = (rad * _position_factor(rig).to(dev, dt)).reshape(B, P, 3, h * w).transpose(-1, -2)
        return ControlVariate(block_radiance=None, texel=None, known=None,
                              grid_radiance=torch.nn.functional.pad(_vertex_radiance(rig, ltc_grid, rad),
                                                                    (0, vertex_packet_width(P) - 3 * P)),
                              ltc_table=default_table().grid.to(dev, dt), cell_radiance=cells)
    options = (mode, blocks, ltc_min_roughness, ltc_min_cos_view, ltc_grid, ltc_cells_min_roughness, ltc_window,
               ltc_window_min_roughness)
    terms = LAST_MATERIALS.terms_for(svbrdf, rig, options, lambda: _material_terms(svbrdf, rig, *options))
    lbar = _block_average(rad, blocks)  # (B, P, 3, K^2)

    if terms.block_ff is None:
        known = torch.zeros(B, P, N, 3, dtype=dt, device=dev)
    else:
        known = torch.bmm(terms.block_ff, lbar.reshape(B, P * 3, -1).transpose(1, 2)).reshape(B, -1, P, 3)
        known = terms.kdd[:, None] * known.permute(0, 2, 1, 3)  # (B, P, N, 3)
    spec = torch.zeros(B, N, P, 3, dtype=dt, device=dev)
    if terms.lobe_grid is not None:
        t = _vertex_radiance(rig, ltc_grid, rad)  # (B, V, 3 P)
        both = torch.bmm(terms.lobe_grid.reshape(B, 2 * N, -1), t).reshape(B, N, 2, P, 3)
        per_cell = terms.s_cells[:, :, None] * both[:, :, 0] + terms.kd_cells[:, :, None] * both[:, :, 1]
        known = known + per_cell.permute(0, 2, 1, 3)
    if terms.window is not None:
        lw = terms.window
        known = known + torch.zeros(B * N, P, 3, dtype=dt, device=dev).index_put(
            (lw.idx,), lw.s[:, None] * _window_integral(rig, lw, ltc_window, rad)).reshape(B, N, P, 3).permute(0, 2, 1, 3)
    if terms.block is not None:
        cp = lbar.permute(0, 3, 1, 2).reshape(B * blocks * blocks, P, 3)[terms.block]  # (B N, P, 3)
        spec = (cp * terms.spec_weight[:, None]).reshape(B, N, P, 3)
        known = known + (spec * terms.spec_ff.reshape(B, N, 1, 1)).permute(0, 2, 1, 3)
    texel = torch.cat([terms.m_entries, terms.kdd, spec.reshape(B, N, 3 * P), *terms.extra], -1)
    return ControlVariate(block_radiance=lbar, texel=texel,
                          known=known.permute(0, 1, 3, 2).reshape(B, P, 3, H, W), lobe_grid=terms.lobe_grid)
