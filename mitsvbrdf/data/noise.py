"""Texture primitives for the procedural SVBRDF generator, batched and vectorised in torch.

Coordinates: a ``size x size`` texel grid over the unit sample square, ``x = (j + 1/2) / size``
to the right and ``y = (i + 1/2) / size`` *down* the rows (image order). Patterns need no physical
orientation; only the normals do, and :func:`mitsvbrdf.data.procedural.height_to_normal` converts
heights to tangent-space normals with y up. Lengths (heights, widths) are in sample units (the
sample side is 1), so a material looks the same at every resolution.

Per-material parameters are tensors of shape (B,); fields are (B, H, W) float tensors on the
parameters' device. Nothing here draws random numbers: randomness enters as tensors (spectral
coefficients, per-cell tables) drawn by the caller from a per-material generator, which keeps
every material reproducible whatever the batch it is built in.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def col(t: Tensor) -> Tensor:
    """(B,) -> (B, 1, 1) for broadcasting against (B, H, W) fields."""
    return t.reshape(-1, 1, 1)


def grid(size: int, device=None, dtype: torch.dtype = torch.float32) -> tuple[Tensor, Tensor]:
    """Texel-centre coordinates ``x, y``, each (1, size, size): x right, y down, in (0, 1)."""
    t = (torch.arange(size, device=device, dtype=dtype) + 0.5) / size
    y, x = torch.meshgrid(t, t, indexing="ij")
    return x.unsqueeze(0), y.unsqueeze(0)


def rotate(x: Tensor, y: Tensor, angle: Tensor) -> tuple[Tensor, Tensor]:
    """Rotate coordinates by ``angle`` (B,) radians about the sample centre; returns (B, H, W) each."""
    c, s = col(torch.cos(angle)), col(torch.sin(angle))
    xc, yc = x - 0.5, y - 0.5
    return c * xc + s * yc + 0.5, -s * xc + c * yc + 0.5


def smoothstep(e0, e1, x: Tensor) -> Tensor:
    """Hermite step: 0 for x <= e0, 1 for x >= e1 (e0 < e1; tensors broadcast)."""
    t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def lerp(a, b, t):
    return a + (b - a) * t


def spectral_noise(coef: Tensor, size: int, *, beta, fmin, fmax, angle: Tensor | None = None,
                   aniso: Tensor | None = None, unit: str = "std") -> Tensor:
    """Gaussian random field with a power-law spectrum, by inverse FFT (periodic over the sample).

    Args:
        coef: (B, 2F+1, F+1) complex standard-normal coefficients for the frequencies
            ky in [-F, F], kx in [0, F] (cycles per sample side). Fixed per material, so the same
            coefficients give the same field at any ``size`` (frequencies at or above the
            Nyquist limit size/2 are dropped).
        beta: (B,) spectral slope, power ~ f^-beta (0 white, 2 rough terrain, 3+ smooth).
        fmin, fmax: (B,) soft band edges in cycles per sample (Gaussian roll-offs).
        angle, aniso: optional (B,) streak direction (radians, in the x-right/y-down frame) and
            elongation >= 1: the spectrum is compressed along the streak direction, so features
            are ``aniso`` times longer along it than across.
        unit: "std" scales the field to unit standard deviation, "slope" to unit RMS gradient
            magnitude (in sample units), both computed over the full band F, not the cropped one.
    Returns:
        (B, size, size) real field, zero mean.
    """
    B, rows, F1 = coef.shape
    F = F1 - 1
    dev = coef.device
    fdt = torch.float32
    ky = torch.arange(-F, F + 1, device=dev, dtype=fdt).view(1, -1, 1)
    kx = torch.arange(0, F + 1, device=dev, dtype=fdt).view(1, 1, -1)
    if angle is not None:
        c, s = col(torch.cos(angle)), col(torch.sin(angle))
        k_along = kx * c + ky * s
        k_across = -kx * s + ky * c
        f = torch.sqrt((k_along * col(aniso)) ** 2 + k_across ** 2)
    else:
        f = torch.sqrt(kx * kx + ky * ky)
    fmin, fmax, beta = col(torch.as_tensor(fmin, device=dev, dtype=fdt)), \
        col(torch.as_tensor(fmax, device=dev, dtype=fdt)), col(torch.as_tensor(beta, device=dev, dtype=fdt))
    fc = f.clamp_min(0.5)
    amp = fc.pow(-beta / 2) * (1.0 - torch.exp(-(f / fmin) ** 2)) * torch.exp(-(f / fmax) ** 2)
    amp = amp * (f > 0)
    weight = torch.where(kx > 0, 2.0, 0.5)
    if unit == "std":
        var = (weight * amp * amp).sum(dim=(1, 2))
    elif unit == "slope":
        var = (weight * amp * amp * (2 * math.pi) ** 2 * (kx * kx + ky * ky)).sum(dim=(1, 2))
    else:
        raise ValueError(f"unit must be 'std' or 'slope', got {unit!r}")
    amp = amp / col(var.clamp_min(1e-30).sqrt())
    K = min(F, (size - 1) // 2)
    sub = coef[:, F - K:F + K + 1, :K + 1] * amp[:, F - K:F + K + 1, :K + 1]
    spec = torch.zeros(B, size, size // 2 + 1, dtype=coef.dtype, device=dev)
    spec[:, :K + 1, :K + 1] = sub[:, K:]  # ky = 0 .. K
    if K > 0:
        spec[:, size - K:, :K + 1] = sub[:, :K]  # ky = -K .. -1
    return torch.fft.irfft2(spec, s=(size, size), norm="forward")


def lookup(table: Tensor, iy: Tensor, ix: Tensor) -> Tensor:
    """Per-cell random values: ``table`` (B, N, N, K) at integer cells (iy, ix) taken modulo N.

    ``iy``, ``ix`` are integer-valued (B, H, W) tensors (any float/int dtype); returns (B, K, H, W).
    """
    B, N, _, K = table.shape
    iy = torch.remainder(iy.long(), N)
    ix = torch.remainder(ix.long(), N)
    return lookup_flat(table.reshape(B, N * N, K), iy * N + ix)


def lookup_flat(flat: Tensor, idx: Tensor) -> Tensor:
    """``flat`` (B, M, K) gathered at ``idx`` (B, H, W) long in [0, M); returns (B, K, H, W)."""
    B, M, K = flat.shape
    _, H, W = idx.shape
    src = flat.transpose(1, 2)  # (B, K, M): gather along the last dim writes (B, K, HW) in place
    if K == 1:
        return torch.gather(src, 2, idx.reshape(B, 1, H * W)).reshape(B, 1, H, W)
    g = torch.gather(src.contiguous(), 2, idx.reshape(B, 1, H * W).expand(B, K, H * W))
    return g.reshape(B, K, H, W)


def cellular(x: Tensor, y: Tensor, n: Tensor, table: Tensor, jitter: Tensor) -> dict[str, Tensor]:
    """Voronoi cells of a jittered grid of ``n`` x ``n`` feature points (periodic with period 1
    when ``x``, ``y`` are the unrotated grid).

    Args:
        x, y: (B or 1, H, W) coordinates in sample units.
        n: (B,) integer-valued cells per sample side, 1 <= n <= N.
        table: (B, N, N, 2) uniform [0, 1) jitter of each cell's feature point.
        jitter: (B,) in [0, 1]: 0 puts points at cell centres (a regular grid), 1 anywhere in the cell.
    Returns a dict of (B, H, W) tensors:
        ``f1``: distance to the nearest feature point and ``edge``: distance to the cell's border
        (the nearest bisector with any of the 3 x 3 neighbouring points; exact away from strongly
        jittered corners), both in sample units; ``id``: the nearest cell's flat index
        ``iy * N + ix`` (long) for :func:`lookup_flat`; ``dx``, ``dy``: offset from the nearest
        feature point, sample units.
    """
    B, N = table.shape[0], table.shape[1]
    nn = col(n)
    px, py = x * nn, y * nn
    cx, cy = torch.floor(px), torch.floor(py)
    flat = table.reshape(B, N * N, 2)
    jit = col(jitter)
    d1 = None
    points = []
    for oy in (-1.0, 0.0, 1.0):
        for ox in (-1.0, 0.0, 1.0):
            gx, gy = cx + ox, cy + oy
            idx = torch.remainder(gy, nn).long() * N + torch.remainder(gx, nn).long()
            j = lookup_flat(flat, idx)
            fx = gx + 0.5 + (j[:, 0] - 0.5) * jit
            fy = gy + 0.5 + (j[:, 1] - 0.5) * jit
            points.append((fx, fy))
            d = (px - fx) ** 2 + (py - fy) ** 2
            if d1 is None:
                d1, p1x, p1y, id1 = d, fx, fy, idx
                continue
            closer = d < d1
            d1 = torch.where(closer, d, d1)
            p1x = torch.where(closer, fx, p1x)
            p1y = torch.where(closer, fy, p1y)
            id1 = torch.where(closer, idx, id1)
    edge = torch.full_like(px, float("inf"))
    for fx, fy in points:
        ex, ey = fx - p1x, fy - p1y
        el2 = ex * ex + ey * ey
        dist = (((p1x + fx) / 2 - px) * ex + ((p1y + fy) / 2 - py) * ey) * torch.rsqrt(el2.clamp_min(1e-12))
        edge = torch.where(el2 > 1e-12, torch.minimum(edge, dist), edge)
    return {"f1": torch.sqrt(d1) / nn, "edge": edge.clamp_min(0.0) / nn, "id": id1,
            "dx": (px - p1x) / nn, "dy": (py - p1y) / nn}
