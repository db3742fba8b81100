"""The ``importance`` integrator's estimators that the benchmarks compare, as scene-file variants.

Each is a set of integrator options (plugins/importance_integrator.py) written into a copy of the
default scene, every option that differs between them spelled out, so that a row keeps its meaning
when the integrator's defaults change; :data:`DEFAULT` names the one that equals the defaults
(tests/test_integrator_options.py checks that).
"""

from __future__ import annotations

from pathlib import Path

import mitsvbrdf as ms
from mitsvbrdf.scene_xml import write_integrator_options
from mitsvbrdf.render.mitsuba import release_scenes
from mitsvbrdf.rig import DEFAULT_SCENE

DEFAULT = "ltc-grid-window-8"
#: name -> integrator options ("plain" is the integrator before variance reduction: independent
#: samples, no control variate, its kernels traced at every render; "plain-frozen" the same with
#: the recorded kernels replayed, as every other estimator here and the integrator's default do)
ESTIMATORS = {"plain": {"sampler": "independent", "control_variate": "none", "freeze": False},
              "plain-frozen": {"sampler": "independent", "control_variate": "none"},
              "stratified": {"sampler": "stratified", "control_variate": "none"},
              "diffuse-cv": {"control_variate": "diffuse"},
              "ltc-cv": {"control_variate": "ltc"},
              "ltc-cv-4-blocks": {"control_variate": "ltc", "cv_blocks": 4},
              "ltc-cv-16-blocks": {"control_variate": "ltc", "cv_blocks": 16},
              "ltc-cv-pattern-light": {"control_variate": "ltc", "light_sampling": "patterns"},
              "ltc-cells": {"control_variate": "ltc-cells", "ltc_grid": 16, "ltc_cells_min_roughness": 0.2,
                            "ltc_window": 8, "ltc_window_min_roughness": 0.02},
              "ltc-cells-no-window": {"control_variate": "ltc-cells", "ltc_grid": 16, "ltc_cells_min_roughness": 0.2,
                                      "ltc_window": 0},
              "ltc-cells-window-4": {"control_variate": "ltc-cells", "ltc_window": 4},
              "ltc-cells-8-grid": {"control_variate": "ltc-cells", "ltc_grid": 8, "ltc_cells_min_roughness": 0.3,
                                   "ltc_window": 0},
              "ltc-cells-8-grid-window": {"control_variate": "ltc-cells", "ltc_grid": 8, "ltc_cells_min_roughness": 0.2,
                                          "ltc_window": 8, "ltc_window_min_roughness": 0.02},
              "ltc-cells-32-grid": {"control_variate": "ltc-cells", "ltc_grid": 32, "ltc_cells_min_roughness": 0.1,
                                    "ltc_window": 0},
              "ltc-grid": {"control_variate": "ltc-grid", "ltc_grid": 4, "ltc_cells_min_roughness": 0.2,
                           "ltc_window": 0},
              "ltc-grid-8": {"control_variate": "ltc-grid", "ltc_grid": 8, "ltc_cells_min_roughness": 0.2,
                             "ltc_window": 0},
              "ltc-grid-window-4": {"control_variate": "ltc-grid", "ltc_grid": 4, "ltc_cells_min_roughness": 0.2,
                                    "ltc_window": 4, "ltc_window_min_roughness": 0.02},
              "ltc-grid-8-window-8": {"control_variate": "ltc-grid", "ltc_grid": 8, "ltc_cells_min_roughness": 0.2,
                                      "ltc_window": 8, "ltc_window_min_roughness": 0.02},
              DEFAULT: {"control_variate": "ltc-grid", "ltc_grid": 4, "ltc_cells_min_roughness": 0.2,
                        "ltc_window": 8, "ltc_window_min_roughness": 0.02}}
ESTIMATORS[f"{DEFAULT}-traced"] = {**ESTIMATORS[DEFAULT], "freeze": False}
for _options in ESTIMATORS.values():
    _options.setdefault("freeze", True)


def estimator_names(spec: str, always: tuple[str, ...] = ()) -> list[str]:
    """The estimators of a comma-separated ``spec`` ("" : all of them) in :data:`ESTIMATORS`' order,
    with ``always`` added.

    Raises:
        SystemExit: a name that is not an estimator (the command-line error of the benchmarks).
    """
    asked = [n for n in spec.split(",") if n]
    unknown = [n for n in asked if n not in ESTIMATORS]
    if unknown:
        raise SystemExit(f"unknown estimators {', '.join(unknown)}; known: {', '.join(ESTIMATORS)}")
    return [n for n in ESTIMATORS if not asked or n in asked or n in always]


def estimator_rigs(work: Path, names=None) -> dict[str, ms.Rig]:
    """A rig per estimator (``names``: a subset, default all): the default scene with that
    estimator's integrator options, written into ``work``."""
    scene = DEFAULT_SCENE
    return {name: ms.Rig.from_scene(write_integrator_options(scene, work / f"{name}.xml", **ESTIMATORS[name]))
            for name in (names or ESTIMATORS)}


def render_alone(svbrdf, patterns, rig: ms.Rig, spp: int, seed: int = 1):
    """``ms.render(..., method="mitsuba")`` with every other scene released first
    (:func:`mitsvbrdf.render.mitsuba.release_scenes`), as in a process that renders through one
    scene (a training run): with the other estimators' scenes alive, a replaying estimator would
    record its kernels again whenever another one rendered in between. The scene is loaded again
    when it was released: time a render that follows one of the same rig."""
    release_scenes(keep=rig.source)
    return ms.render(svbrdf, patterns, rig, method="mitsuba", spp=spp, seed=seed)
