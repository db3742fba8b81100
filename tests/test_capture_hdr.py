"""HDR: camera response calibration from a bracket, and merging brackets to linear radiance."""

import numpy as np
import pytest

from mitsvbrdf.capture import Response, calibrate_response, merge_hdr

TIMES = np.array([1 / 250, 1 / 60, 1 / 15, 1 / 4, 1.0])


def camera(radiance: np.ndarray, t: float, gamma: float = 2.2, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """A simulated camera: z = (E t)^(1/gamma) + read noise, clipped, quantised to 8 bits."""
    z = np.clip(radiance * t, 0, None) ** (1 / gamma)
    z = z + noise * np.random.default_rng(seed).standard_normal(z.shape)
    return np.round(np.clip(z, 0, 1) * 255) / 255


@pytest.fixture()
def scene():
    rng = np.random.default_rng(1)
    return np.exp(rng.uniform(np.log(0.05), np.log(200.0), size=(24, 24, 3)))  # 3.6 decades


def test_calibration_recovers_a_gamma_response(scene):
    pts = scene.reshape(-1)[::7][:300]
    values = np.stack([camera(pts, t) for t in TIMES])
    g = calibrate_response(values, TIMES)
    truth = Response.gamma(2.2).log_exposure
    mid = slice(20, 246)  # codes the bracket sees well
    # g is relative: compare after removing the constant
    diff = (g.log_exposure - truth)[mid]
    assert np.abs(diff - diff.mean()).max() < 0.05


def test_merge_recovers_radiance_over_the_bracket_range(scene):
    frames = np.stack([camera(scene, t, noise=0.002, seed=i) for i, t in enumerate(TIMES)])
    res = merge_hdr(frames, TIMES, Response.gamma(2.2))
    ok = np.isfinite(res.radiance)
    assert ok.mean() > 0.99
    rel = np.abs(res.radiance[ok] / scene[ok] - 1)
    assert np.median(rel) < 0.01 and rel.max() < 0.08


def test_pixels_saturated_in_every_frame_are_reported_not_guessed():
    scene = np.full((2, 2, 3), 10.0)
    scene[0, 0] = 1e6
    frames = np.stack([camera(scene, t) for t in TIMES])
    res = merge_hdr(frames, TIMES, Response.gamma(2.2))
    assert res.saturated[0, 0].all() and np.isnan(res.radiance[0, 0]).all()
    assert np.isfinite(res.radiance[1, 1]).all() and not res.saturated[1, 1].any()


def test_bad_brackets_are_refused():
    with pytest.raises(ValueError, match="K >= 2"):
        calibrate_response(np.zeros((1, 10)), np.array([1.0]))
    with pytest.raises(ValueError, match="positive"):
        calibrate_response(np.zeros((2, 10)), np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="exposure times"):
        merge_hdr(np.zeros((3, 2, 2, 3)), TIMES, Response.gamma())
