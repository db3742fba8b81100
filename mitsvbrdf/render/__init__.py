"""Renderers of paper Eq. 1 behind one contract.

``render(svbrdf, patterns, rig, method=...)`` returns (B, P, 3, H, W) linear radiance on the
sample's texel grid, differentiable w.r.t. patterns and maps. Methods:

* ``"reference"``: deterministic quadrature in torch (:mod:`.reference`), accurate at every
  roughness; ``settings`` sets its accuracy, ``spp`` does not apply.
* ``"mitsuba"``: Monte Carlo through the scene file's own plugins (:mod:`.mitsuba`), ``spp``
  samples per texel, ``seed`` picks the sample set; ``lobes`` must be "both".

The LTC renderer joins this dispatch with its own issue.
"""

from __future__ import annotations

from torch import Tensor

from ..rig import Rig
from .quadrature import QuadratureSettings
from .reference import render_reference

METHODS = ("reference", "mitsuba")


def render(svbrdf, patterns: Tensor, rig: Rig, method: str = "reference", *, spp: int = 64,
           lobes: str = "both", settings: QuadratureSettings | None = None, progress=None,
           seed: int = 0) -> Tensor:
    """Render ``svbrdf`` (B materials) under ``patterns`` ((P, 3, h, w) or (B, P, 3, h, w)) with ``rig``.

    Returns (B, P, 3, H, W) float32 linear radiance on the maps' device.
    """
    if method == "reference":
        return render_reference(svbrdf, patterns, rig, lobes=lobes, settings=settings, progress=progress)
    if method == "mitsuba":
        if lobes != "both":
            raise ValueError("method='mitsuba' renders both lobes; use method='reference' for one lobe")
        from .mitsuba import render_mitsuba

        return render_mitsuba(svbrdf, patterns, rig, spp=spp, seed=seed)
    raise ValueError(f"unknown render method {method!r}; available: {', '.join(METHODS)}")


__all__ = ["render", "render_reference", "QuadratureSettings", "METHODS"]
