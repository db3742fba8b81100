"""Colour calibration from a simulated ColorChecker capture."""

import numpy as np
import pytest

from mitsvbrdf.capture.color import chart_reference_rgb, delta_e_2000, fit_color_matrix


def camera_rgb(reference: np.ndarray, noise: float, seed: int = 0) -> np.ndarray:
    """What a camera with crosstalk sees of the chart: an unknown matrix, exposure and noise."""
    crosstalk = np.array([[0.75, 0.20, 0.05], [0.10, 0.80, 0.10], [0.02, 0.18, 0.80]])
    measured = 0.6 * reference @ crosstalk.T
    return measured + noise * np.random.default_rng(seed).standard_normal(measured.shape)


def test_reference_chart_white_patch_is_near_neutral():
    ref = chart_reference_rgb()
    assert ref.shape == (24, 3)
    white = ref[18]  # "white 9.5"
    assert np.ptp(white) / white.mean() < 0.1  # a wrong illuminant adaptation gives casts of 20-30%


def test_fitted_matrix_brings_the_chart_below_one_delta_e():
    ref = chart_reference_rgb()
    measured = camera_rgb(ref, noise=0.001)
    before = delta_e_2000(measured)
    m = fit_color_matrix(measured)
    after = delta_e_2000(measured @ m.T)
    assert before.mean() > 3.0  # the crosstalk is visible
    assert after.mean() < 1.0 and np.median(after) < 1.0


def test_chart_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match="measured patches"):
        fit_color_matrix(np.ones((10, 3)))
