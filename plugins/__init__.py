"""mitsvbrdf_plugins: the project's Mitsuba 3 plugins written in Python.

    lcd          emitter: an LCD showing patterns through the display model (lcd_emitter.py)
    svbrdf_ggx   BSDF: the project's GGX SVBRDF with texel maps (svbrdf_bsdf.py)
    importance   integrator: direct light from the LCD, all patterns in one pass
                 (importance_integrator.py)

Mitsuba plugin classes derive from variant-specific base classes, so they are defined and
registered after a variant is chosen: call :func:`register` (``mitsvbrdf.backend`` picks and sets
the variant safely), or import this package after ``mi.set_variant`` to llvm_ad_rgb or
cuda_ad_rgb and it registers itself.
Objects of a loaded scene are instances of these Python classes; :func:`plugin_class` names the
class registered for a variant, so that code identifies a plugin by its type.
"""

from __future__ import annotations

import importlib
import sys

from mitsvbrdf.backend import VARIANTS, import_mitsuba

_MODULES = {"lcd": ("lcd_emitter", "LCDEmitter"), "svbrdf_ggx": ("svbrdf_bsdf", "SVBRDFGGX"),
            "importance": ("importance_integrator", "ImportanceIntegrator")}
"""Plugin name -> (module, class), in the order the modules load (the integrator imports the others)."""

_CLASSES: dict[str, dict[str, type]] = {}
"""Variant -> plugin name -> the Python class registered under that name for that variant."""


def _load_classes() -> dict[str, type]:
    """Plugin name -> class, defined anew on the current variant's Mitsuba base classes."""
    classes = {}
    for name, (module, cls) in _MODULES.items():
        full = f"{__name__}.{module}"
        # Reload so classes derive from the *current* variant's mi.Emitter/mi.BSDF/...
        mod = importlib.reload(sys.modules[full]) if full in sys.modules else importlib.import_module(full)
        classes[name] = getattr(mod, cls)
    return classes


def register(variant: str | None = None):
    """Set up the Mitsuba variant (via mitsvbrdf.backend) and register the three plugins for it.

    Args:
        variant: a variant :func:`mitsvbrdf.backend.choose_variant` accepts; None chooses one.
    Returns the ``mitsuba`` module. Idempotent per variant.
    """
    mi = import_mitsuba(variant)
    v = mi.variant()
    if v not in _CLASSES:
        # The classes, not their modules, are registered: a later reload for another variant
        # rebinds the modules' names but must not change what this variant constructs.
        classes = _CLASSES[v] = _load_classes()
        mi.register_emitter("lcd", classes["lcd"])
        mi.register_bsdf("svbrdf_ggx", classes["svbrdf_ggx"])
        mi.register_integrator("importance", classes["importance"])
    return mi


def plugin_class(name: str, variant: str | None = None) -> type:
    """The Python class registered as plugin ``name`` for ``variant`` (default: the current one).

    Args:
        name: "lcd", "svbrdf_ggx" or "importance".
        variant: a Mitsuba variant; None means ``mitsuba.variant()``.
    Raises:
        ValueError: unknown plugin name, or the plugins are not registered for the variant.
    """
    if name not in _MODULES:
        raise ValueError(f"unknown mitsvbrdf plugin {name!r}; the plugins are {', '.join(_MODULES)}")
    if variant is None:
        mi = sys.modules.get("mitsuba")
        variant = mi.variant() if mi is not None else None
    if variant not in _CLASSES:
        raise ValueError(f"the mitsvbrdf plugins are not registered for Mitsuba variant {variant!r}; "
                         f"call mitsvbrdf_plugins.register() before loading a scene")
    return _CLASSES[variant][name]


def _register_if_variant_set() -> None:
    # Only for a variant the plugins run on: code may have set another (e.g. scalar_rgb) for its own use.
    mi = sys.modules.get("mitsuba")
    if mi is not None and mi.variant() in VARIANTS:
        register(mi.variant())


_register_if_variant_set()
