"""Renderers of paper Eq. 1 behind one contract.

``render(svbrdf, patterns, rig, method=...)`` returns (B, P, 3, H, W) linear radiance on the
sample's texel grid, differentiable w.r.t. patterns and maps. Methods:

* ``"reference"``: deterministic quadrature in torch (:mod:`.reference`), accurate at every
  roughness; ``settings`` sets its accuracy, ``spp`` does not apply.

The Mitsuba (path-traced) and LTC renderers join this dispatch with their own issues.
"""

from __future__ import annotations

from torch import Tensor

from ..rig import Rig
from .quadrature import QuadratureSettings
from .reference import render_reference

METHODS = ("reference",)


def render(svbrdf, patterns: Tensor, rig: Rig, method: str = "reference", *, spp: int = 64,
           lobes: str = "both", settings: QuadratureSettings | None = None, progress=None) -> Tensor:
    """Render ``svbrdf`` (B materials) under ``patterns`` ((P, 3, h, w) or (B, P, 3, h, w)) with ``rig``.

    Returns (B, P, 3, H, W) float32 linear radiance on the maps' device.
    """
    if method == "reference":
        return render_reference(svbrdf, patterns, rig, lobes=lobes, settings=settings, progress=progress)
    raise ValueError(f"unknown render method {method!r}; available: {', '.join(METHODS)}")


__all__ = ["render", "render_reference", "QuadratureSettings", "METHODS"]
