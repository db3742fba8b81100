"""mitsvbrdf_plugins: the project's Mitsuba 3 plugins written in Python.

    lcd          emitter: an LCD showing patterns through the display model (lcd_emitter.py)
    svbrdf_ggx   BSDF: the project's GGX SVBRDF with texel maps (svbrdf_bsdf.py)
    importance   integrator: direct light from the LCD, all patterns in one pass
                 (importance_integrator.py)

Mitsuba plugin classes derive from variant-specific base classes, so they are defined and
registered after a variant is chosen: call :func:`register` (``mitsvbrdf.backend`` picks and sets
the variant safely), or import this package after ``mi.set_variant`` to llvm_ad_rgb or
cuda_ad_rgb and it registers itself.
"""

from __future__ import annotations

import importlib
import sys

_registered: set[str] = set()
_MODULES = ("lcd_emitter", "svbrdf_bsdf", "importance_integrator")


def register(variant: str | None = None):
    """Set up the Mitsuba variant (via mitsvbrdf.backend) and register the three plugins for it.

    Returns the ``mitsuba`` module. Idempotent per variant.
    """
    from mitsvbrdf.backend import import_mitsuba

    mi = import_mitsuba(variant)
    v = mi.variant()
    if v in _registered:
        return mi
    mods = {}
    for name in _MODULES:
        full = f"{__name__}.{name}"
        # Reload so classes derive from the *current* variant's mi.Emitter/mi.BSDF/...
        mods[name] = importlib.reload(sys.modules[full]) if full in sys.modules else importlib.import_module(full)
    mi.register_emitter("lcd", lambda props: mods["lcd_emitter"].LCDEmitter(props))
    mi.register_bsdf("svbrdf_ggx", lambda props: mods["svbrdf_bsdf"].SVBRDFGGX(props))
    mi.register_integrator("importance", lambda props: mods["importance_integrator"].ImportanceIntegrator(props))
    _registered.add(v)
    return mi


def _register_if_variant_set() -> None:
    from mitsvbrdf.backend import VARIANTS

    # Only for a variant the plugins run on: code may have set another (e.g. scalar_rgb) for its own use.
    mi = sys.modules.get("mitsuba")
    if mi is not None and mi.variant() in VARIANTS:
        register(mi.variant())


_register_if_variant_set()
