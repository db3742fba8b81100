"""Which encoding a dataset stores its albedos in, told by the render tile that came with the maps.

A Deschaintre-format 5-tile strip ``[render | normal | diffuse | roughness | specular]`` carries an
image of the material under a flash near the camera, stored display-encoded (8-bit sRGB-like). The
maps alone cannot say whether the stored kd / ks are linear values or sRGB-encoded ones; the render
can: re-render the maps both ways and see which matches.

Geometry (Deschaintre et al. 2018's renderer): the sample spans [-1, 1]^2 in x (right) and y (up),
z = 0, texel (i, j) at its texel centre; positions are in units of the sample's half side. The
flash is a point light at the camera's centre of projection ``p = (x, y, z)``, z > 0, with 1 / d^2
fall-off: ``L_o = f(w_i, w_o) (n . w_i)^+ / d^2`` with ``w_i = w_o`` towards ``p`` (the project's
BRDF, :func:`mitsvbrdf.brdf.brdf`). The dataset's exact flash position and exposure vary per image,
so :func:`fit_flash` fits ``p`` and one global scale per material and hypothesis, in display values
(scale, clip to [0, 1], sRGB curve: :func:`mitsvbrdf.viewing.tonemap`), on the tile's unsaturated
pixels; what is left, the *shape* of the image, decides between the hypotheses.

Hypotheses (:data:`HYPOTHESES`): ``"linear"`` renders the stored kd / ks as they are (the
convention of :meth:`mitsvbrdf.SVBRDF.load`'s default); ``"srgb"`` decodes both with the sRGB
curve first (``SVBRDF.load(..., srgb_albedo=True)``); ``"srgb_kd"`` decodes kd only (sRGB colour
maps, linear F0 values, a common texture-authoring convention).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ..brdf import brdf
from ..viewing import tonemap
from ..svbrdf import SVBRDF, srgb_to_linear

HYPOTHESES = ("linear", "srgb", "srgb_kd")
#: Tile pixels with a channel at or above this display value are saturated (clipped) and not fitted.
SATURATED = 0.98
#: Starting flash positions of the fit (half sides): over the centre and off it, at two heights.
STARTS = ((0.0, 0.0, 2.75), (0.4, 0.4, 2.0), (-0.4, 0.4, 2.0), (0.4, -0.4, 2.0), (-0.4, -0.4, 2.0), (0.0, 0.0, 1.4))


def albedos(svbrdf: SVBRDF, hypothesis: str) -> tuple[Tensor, Tensor]:
    """Linear ``(kd, ks)`` (B, 3, H, W) that rendering uses under ``hypothesis`` (see the module)."""
    if hypothesis == "linear":
        return svbrdf.diffuse, svbrdf.specular
    if hypothesis == "srgb":
        return srgb_to_linear(svbrdf.diffuse), srgb_to_linear(svbrdf.specular)
    if hypothesis == "srgb_kd":
        return srgb_to_linear(svbrdf.diffuse), svbrdf.specular
    raise ValueError(f"hypothesis must be one of {HYPOTHESES}, got {hypothesis!r}")


def flash_image(svbrdf: SVBRDF, position: Tensor, hypothesis: str = "linear") -> Tensor:
    """Linear radiance (B, 3, H, W) under a unit flash at the camera ``position`` (3,) (half sides;
    the module's geometry), albedos read under ``hypothesis``. Differentiable w.r.t. ``position``."""
    B, _, H, W = svbrdf.normal.shape
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    u = (torch.arange(W, device=dev, dtype=dt) + 0.5) / W * 2 - 1
    v = 1 - (torch.arange(H, device=dev, dtype=dt) + 0.5) / H * 2
    x = torch.stack([u[None, :].expand(H, W), v[:, None].expand(H, W), torch.zeros(H, W, device=dev, dtype=dt)])
    d = position.to(dev, dt).view(3, 1, 1) - x
    d2 = (d * d).sum(0, keepdim=True)
    w = (d / d2.sqrt())[None]
    kd, ks = albedos(svbrdf, hypothesis)
    return brdf(svbrdf.normal, w, w, kd, ks, svbrdf.roughness, cosine=True, dim=-3) / d2[None]


def _shrink(svbrdf: SVBRDF, tile: Tensor, size: int) -> tuple[SVBRDF, Tensor]:
    """Area-average maps and tile to ``size`` px (normals renormalised) for a fast fit."""
    H = svbrdf.resolution[0]
    if size >= H:
        return svbrdf, tile
    f = H // size
    pool = lambda t: F.avg_pool2d(t, f)  # noqa: E731
    n = pool(svbrdf.normal)
    n = n / n.norm(dim=1, keepdim=True).clamp_min(1e-8)
    small = SVBRDF(normal=n, diffuse=pool(svbrdf.diffuse), roughness=pool(svbrdf.roughness),
                   specular=pool(svbrdf.specular), check=False)
    return small, pool(tile)


def fit_flash(svbrdf: SVBRDF, tile: Tensor, hypothesis: str, *, fit_size: int = 64, steps: int = 120,
              starts=STARTS) -> dict:
    """Fit flash position and global scale so the toned render matches ``tile``; score the match.

    Args:
        svbrdf: one material (B = 1), maps as loaded (stored values).
        tile: (1, 3, H, W) or (3, H, W) the render tile, display values in [0, 1] as stored.
        hypothesis: one of :data:`HYPOTHESES` (see the module docstring).
        fit_size: the fit runs on maps and tile area-averaged to this size (then scored at full size).
        steps, starts: Adam steps per start; the starting positions (the best fit is kept).

    Returns:
        ``{"rmse": display-value RMSE over the unsaturated pixels at full size, "corr": Pearson
        correlation of toned render and tile there, "position": (3,) list, "scale": float,
        "image": (1, 3, H, W) the toned render}``.
    """
    tile = (tile if tile.ndim == 4 else tile[None]).to(svbrdf.normal.dtype)
    small, small_tile = _shrink(svbrdf, tile, fit_size)
    ok_small = (small_tile.amax(1, keepdim=True) < SATURATED).expand_as(small_tile)
    best = None
    with torch.enable_grad():
        for start in starts:
            p = torch.tensor(start, dtype=torch.float32, requires_grad=True)
            with torch.no_grad():  # start the scale at the ratio of means, in linear values
                img = flash_image(small, p, hypothesis)
                tgt = srgb_to_linear(small_tile)
                ls0 = math.log(max(float(tgt[ok_small].mean()), 1e-6) / max(float(img[ok_small].mean()), 1e-12))
            log_scale = torch.tensor(ls0, requires_grad=True)
            opt = torch.optim.Adam([p, log_scale], lr=0.03)
            for _ in range(steps):
                out = tonemap(flash_image(small, p, hypothesis) * log_scale.exp(), exposure=1.0)
                loss = (out - small_tile)[ok_small].square().mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                with torch.no_grad():
                    p[2].clamp_(min=0.2)
            if best is None or float(loss.detach()) < best[0]:
                best = (float(loss.detach()), p.detach().clone(), float(log_scale.detach().exp()))
    _, pos, scale = best
    with torch.no_grad():
        out = tonemap(flash_image(svbrdf, pos, hypothesis) * scale, exposure=1.0)
        ok = (tile.amax(1, keepdim=True) < SATURATED).expand_as(tile)
        a, b = out[ok], tile[ok]
        rmse = float((a - b).square().mean().sqrt())
        corr = float(torch.corrcoef(torch.stack([a, b]))[0, 1])
    return {"rmse": rmse, "corr": corr, "position": pos.tolist(), "scale": scale, "image": out}


def compare_encodings(svbrdf: SVBRDF, tile: Tensor, **fit) -> dict[str, dict]:
    """:func:`fit_flash` under each hypothesis: ``{hypothesis: result}``; the lower ``rmse`` wins."""
    return {h: fit_flash(svbrdf, tile, h, **fit) for h in HYPOTHESES}
