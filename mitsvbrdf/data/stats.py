"""Coverage statistics of a set of SVBRDFs: what range of roughness, albedos and slopes it spans.

Quantities per texel (all maps (B, C, H, W) as in :class:`mitsvbrdf.SVBRDF`):

* ``roughness``: r in [0, 1];
* ``ks``: specular albedo, mean over RGB; ``ks_chroma``: max - min over RGB (coloured metals > 0.1);
* ``kd_luminance``: Rec. 709 luminance of the diffuse albedo (0.2126 R + 0.7152 G + 0.0722 B);
* ``slope_deg``: angle between the normal and the macro normal +z, degrees.

:func:`texel_values` returns them flattened; :func:`material_summary` gives per-material
percentiles; :func:`histogram` bins values for reports.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

QUANTITIES = ("roughness", "ks", "ks_chroma", "kd_luminance", "slope_deg")


def texel_maps(svbrdf) -> dict[str, Tensor]:
    """Per-texel quantities as (B, H, W) tensors (see the module docstring)."""
    ks = svbrdf.specular
    kd = svbrdf.diffuse
    return {
        "roughness": svbrdf.roughness[:, 0],
        "ks": ks.mean(dim=1),
        "ks_chroma": ks.amax(dim=1) - ks.amin(dim=1),
        "kd_luminance": 0.2126 * kd[:, 0] + 0.7152 * kd[:, 1] + 0.0722 * kd[:, 2],
        "slope_deg": torch.rad2deg(torch.acos(svbrdf.normal[:, 2].clamp(-1.0, 1.0))),
    }


def texel_values(svbrdf) -> dict[str, Tensor]:
    """Per-texel quantities flattened over all materials: (B * H * W,) each."""
    return {k: v.reshape(-1) for k, v in texel_maps(svbrdf).items()}


def material_summary(svbrdf, q: tuple[float, ...] = (0.01, 0.5, 0.99)) -> dict[str, Tensor]:
    """Per-material quantiles: ``{quantity: (B, len(q))}``."""
    qs = torch.tensor(q, dtype=torch.float32)
    out = {}
    for k, v in texel_maps(svbrdf).items():
        flat = v.reshape(v.shape[0], -1).float()
        out[k] = torch.quantile(flat, qs.to(flat.device), dim=1).T.cpu()
    return out


def histogram(values: Tensor, edges: list[float]) -> list[float]:
    """Fraction of ``values`` in each bin [edges[i], edges[i+1]) (the last bin closed)."""
    v = values.reshape(-1).float().cpu()
    e = torch.tensor(edges, dtype=torch.float32)
    idx = torch.bucketize(v, e, right=True) - 1
    idx = torch.where(v == e[-1], torch.full_like(idx, len(edges) - 2), idx)
    ok = (idx >= 0) & (idx < len(edges) - 1)
    counts = torch.bincount(idx[ok], minlength=len(edges) - 1).float()
    return (counts / max(1, v.numel())).tolist()


def log_edges(lo: float, hi: float, n: int) -> list[float]:
    """``n`` log-spaced bins from lo to hi (n + 1 edges)."""
    a, b = math.log(lo), math.log(hi)
    return [math.exp(a + (b - a) * i / n) for i in range(n + 1)]
