"""Colour calibration from a photographed ColorChecker (colour-science's reference data).

The chart's 24 reference colours (CIE xyY under the chart's illuminant, D50) are converted to
linear sRGB (D65, Bradford adaptation), the working space of the renderers. A 3x3 matrix M maps
the camera's linear RGB of each patch (averaged over the patch, from an HDR merge) to those
references by least squares: ``reference ~= M @ measured``. Accuracy is reported as CIE Delta E
2000 per patch, computed by colour-science in CIELAB (D65), with the exposure's unknown overall
scale fitted out first.
"""

from __future__ import annotations

import numpy as np

CHART = "ColorChecker24 - After November 2014"


def chart_reference_rgb(chart: str = CHART) -> np.ndarray:
    """(24, 3) linear sRGB (D65) of the chart's patches, in the chart's order."""
    import colour

    cc = colour.CCS_COLOURCHECKERS[chart]
    xyy = np.array(list(cc.data.values()))
    xyz = colour.xyY_to_XYZ(xyy)
    return colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], illuminant=cc.illuminant,
                             chromatic_adaptation_transform="Bradford", apply_cctf_encoding=False)


def fit_color_matrix(measured: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """3x3 M with reference ~= M @ measured (rows of (N, 3) linear RGB), least squares."""
    measured = np.asarray(measured, dtype=np.float64)
    reference = chart_reference_rgb() if reference is None else np.asarray(reference, dtype=np.float64)
    if measured.shape != reference.shape or measured.ndim != 2 or measured.shape[1] != 3 or measured.shape[0] < 3:
        raise ValueError(f"measured patches must be (N >= 3, 3) like the reference {reference.shape}, got {measured.shape}")
    m, *_ = np.linalg.lstsq(measured, reference, rcond=None)
    return m.T


def delta_e_2000(rgb: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Delta E 2000 (N,) between linear sRGB patches and the reference, after fitting the single
    overall scale (exposure) that minimises the squared RGB error."""
    import colour

    reference = chart_reference_rgb() if reference is None else np.asarray(reference, dtype=np.float64)
    rgb = np.asarray(rgb, dtype=np.float64)
    scale = float((rgb * reference).sum() / max((rgb * rgb).sum(), 1e-30))
    space = colour.RGB_COLOURSPACES["sRGB"]

    def lab(x):
        xyz = colour.RGB_to_XYZ(x, space, apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, space.whitepoint)

    return colour.delta_E(lab(rgb * scale), lab(reference), method="CIE 2000")
