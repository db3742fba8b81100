"""mitsvbrdf: sparse SVBRDF acquisition with adaptive illumination multiplexing.

Public API (docs/conventions.md has the units, frames and shapes):

    rig = Rig.from_scene()                # the default rig, mitsvbrdf/scenes/lcd_rig.xml
    svbrdf = SVBRDF.load(path)            # or SVBRDF.constant(...)
    imgs = render(svbrdf, patterns, rig)  # (B, P, 3, H, W)
    lpdf = importance(normal, roughness, rig)
    spec = separate_specular(imgs, patterns, rig)
"""

from .brdf import ALPHA_MIN, brdf
from .errors import (BackendError, ImageFileError, MaterialError, MitsvbrdfError, PatternError,
                     SceneError)
from .importance import importance
from .patterns import load_patterns, pattern_family
from .render import QuadratureSettings, render
from .rig import DisplayModel, Rig
from .separation import diffuse_irradiance, separate_specular
from .svbrdf import SVBRDF, decode_maps, encode_maps

__version__ = "0.1.0"

__all__ = [
    "ALPHA_MIN", "brdf", "Rig", "DisplayModel", "SVBRDF", "encode_maps", "decode_maps", "render",
    "QuadratureSettings", "importance", "separate_specular", "diffuse_irradiance", "pattern_family",
    "load_patterns", "MitsvbrdfError", "MaterialError", "ImageFileError", "SceneError",
    "PatternError", "BackendError",
]
