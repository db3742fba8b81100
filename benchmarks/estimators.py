"""The ``importance`` integrator's estimators that the benchmarks compare, as scene-file variants.

Each is a set of integrator options (plugins/importance_integrator.py) written into a copy of the
default scene; the empty set is the scene file's default estimator.
"""

from __future__ import annotations

from pathlib import Path

import mitsvbrdf as ms
from mitsvbrdf.capture.scene_file import write_integrator_options
from mitsvbrdf.rig import DEFAULT_SCENE

DEFAULT = "ltc-cv"
#: name -> integrator options ("plain" is the integrator before variance reduction)
ESTIMATORS = {"plain": {"sampler": "independent", "control_variate": "none"},
              "stratified": {"sampler": "stratified", "control_variate": "none"},
              "diffuse-cv": {"control_variate": "diffuse"},
              DEFAULT: {},
              "ltc-cv-4-blocks": {"cv_blocks": 4},
              "ltc-cv-16-blocks": {"cv_blocks": 16},
              "ltc-cv-pattern-light": {"light_sampling": "patterns"}}


def estimator_rigs(work: Path, names=None) -> dict[str, ms.Rig]:
    """A rig per estimator (``names``: a subset, default all): the default scene with that
    estimator's integrator options, written into ``work``."""
    scene = DEFAULT_SCENE
    return {name: ms.Rig.from_scene(write_integrator_options(scene, work / f"{name}.xml", **ESTIMATORS[name]))
            for name in (names or ESTIMATORS)}
