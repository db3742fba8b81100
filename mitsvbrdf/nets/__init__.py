"""The networks of the method (paper Sec. 3.5), built from one NAFNet block.

* :class:`LightingPredictor` (G_l): I_0 + L_pdf -> 4 adaptive patterns + inverse normal/roughness.
* :class:`PointPredictor` (G_p): per-pixel SIREN reconstruction (training stage 1).
* :class:`SVBRDFPredictor` (G_sc): two-encoder NAFNet, images + I^spec -> maps.
* :class:`LearnedPattern` + :class:`Initializer`: L_0 and the single-image bootstrap.

Parameter counts at default sizes: ``python -m mitsvbrdf.nets`` prints them.
"""

from .blocks import LayerNorm2d, NAFBlock, SimpleGate
from .initializer import Initializer, LearnedPattern, PatternSet
from .io import NetworkFileError, load_network, network_from_record, network_record, parameter_count, save_network
from .lighting import LightingOutput, LightingPredictor
from .nafnet import NAFDecoder, NAFEncoder, NAFNet, diffuse_ratio, normalize_images, with_diffuse_ratio
from .point import PointPredictor
from .svbrdf_net import SVBRDFPredictor

__all__ = ["LayerNorm2d", "NAFBlock", "SimpleGate", "NAFNet", "NAFEncoder", "NAFDecoder", "normalize_images", "diffuse_ratio",
           "LightingPredictor", "LightingOutput", "PointPredictor", "SVBRDFPredictor", "LearnedPattern",
           "Initializer", "PatternSet", "save_network", "load_network", "network_record", "network_from_record",
           "parameter_count", "NetworkFileError", "with_diffuse_ratio"]
