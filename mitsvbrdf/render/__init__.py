"""Renderers of paper Eq. 1 behind one contract.

``render(svbrdf, patterns, rig, method=...)`` returns (B, P, 3, H, W) linear radiance on the
sample's texel grid, differentiable w.r.t. patterns and maps. Methods:

* ``"reference"``: deterministic quadrature in torch (:mod:`.reference`), accurate at every
  roughness; ``settings`` sets its accuracy, ``spp`` does not apply.
* ``"mitsuba"``: Monte Carlo through the scene file's own plugins (:mod:`.mitsuba`), ``spp``
  samples per texel, ``seed`` picks the sample set; ``lobes`` must be "both".
* ``"ltc"``: linearly transformed cosines with the fitted table of :mod:`.ltc_fit`
  (:mod:`.ltc`); ``mode`` "exact" integrates every LCD cell, "prefiltered" the whole LCD once with a
  prefiltered pattern fetch. Deterministic and fast; biased where the LTC misfits the lobe
  (measured in docs/benchmarks/render_tradeoff.md).
"""

from __future__ import annotations

from torch import Tensor

from ..rig import Rig
from .quadrature import QuadratureSettings
from .ltc import render_ltc
from .ltc_fit import default_table
from .reference import render_reference

METHODS = ("reference", "mitsuba", "ltc")


def render(svbrdf, patterns: Tensor, rig: Rig, method: str = "reference", *, spp: int = 64,
           lobes: str = "both", settings: QuadratureSettings | None = None, progress=None,
           seed: int = 0, mode: str = "exact", table=None) -> Tensor:
    """Render ``svbrdf`` (B materials) under ``patterns`` ((P, 3, h, w) or (B, P, 3, h, w)) with ``rig``.

    Returns (B, P, 3, H, W) float32 linear radiance on the maps' device. ``mode`` and ``table``
    apply to ``method="ltc"`` only (``table`` defaults to the shipped fit).
    """
    if method != "ltc" and (mode != "exact" or table is not None):
        raise ValueError(f"mode and table apply to method='ltc' only, not {method!r}")
    if method == "reference":
        return render_reference(svbrdf, patterns, rig, lobes=lobes, settings=settings, progress=progress)
    if method == "mitsuba":
        if lobes != "both":
            raise ValueError("method='mitsuba' renders both lobes; use method='reference' for one lobe")
        from .mitsuba import render_mitsuba  # imports Mitsuba / Dr.Jit: only when asked for

        return render_mitsuba(svbrdf, patterns, rig, spp=spp, seed=seed)
    if method == "ltc":
        return render_ltc(svbrdf, patterns, rig, table if table is not None else default_table(),
                          lobes=lobes, mode=mode)
    raise ValueError(f"unknown render method {method!r}; available: {', '.join(METHODS)}")


__all__ = ["render", "render_reference", "QuadratureSettings", "METHODS"]
