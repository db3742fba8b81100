"""Calibration procedures recover known ground truth from captures made by the simulated rig."""

import numpy as np
import pytest

import mitsvbrdf as ms
from mitsvbrdf.capture.calibrate import (calibrate_camera_response, calibrate_color, calibrate_display,
                                         calibrate_lcd_pose, simulated_bench)
from mitsvbrdf.capture.display import write_display_model
from mitsvbrdf.capture.geometry import _posed, write_lcd_pose
from mitsvbrdf.capture.hdr import Response
from mitsvbrdf.capture.scene_file import read_camera_calibration, write_camera_calibration
from mitsvbrdf.rig import DEFAULT_SCENE

SCENE = DEFAULT_SCENE
CROSSTALK = np.array([[0.8, 0.15, 0.05], [0.1, 0.8, 0.1], [0.05, 0.2, 0.75]])


def test_camera_response_is_recovered_from_a_simulated_bracket(rig):
    truth = Response.gamma(2.2)
    bench, _ = simulated_bench(rig, 16, exposures=np.geomspace(1 / 64, 64, 13), gain=4.0, response=truth)
    fitted = calibrate_camera_response(bench, rig.lcd_cells)
    codes = np.arange(25, 240)
    g_true = truth.log_exposure[codes] - truth.log_exposure[128]
    g_fit = fitted.log_exposure[codes] - fitted.log_exposure[128]
    assert np.abs(g_fit - g_true).max() < 0.05


def test_a_bracket_too_narrow_for_the_response_is_refused(rig):
    bench, _ = simulated_bench(rig, 8, exposures=(1.0, 2.0), gain=4.0, response=Response.gamma(2.2))
    with pytest.raises(ValueError, match="extend the exposures"):
        calibrate_camera_response(bench, rig.lcd_cells)


def test_display_gamma_decay_and_intensity_are_recovered(rig):
    truth = rig.with_display(gamma=2.2, decay_cos_power=1.5, intensity=(2.0, 1.8, 1.5))
    bench, _ = simulated_bench(truth, 12)
    fit = calibrate_display(bench, rig)
    assert fit["gamma"] == pytest.approx(2.2, abs=0.02)
    assert fit["decay_cos_power"] == pytest.approx(1.5, abs=0.05)
    np.testing.assert_allclose(fit["intensity"], [2.0, 1.8, 1.5], rtol=0.01)
    assert fit["relative_rmse"] < 0.01


def test_color_matrix_brings_the_simulated_chart_below_one_delta_e(rig):
    bench, _ = simulated_bench(rig, 48, color_matrix=CROSSTALK)
    fit = calibrate_color(bench, rig)
    assert fit["delta_e"].max() < 1.0
    np.testing.assert_allclose(fit["matrix"], np.linalg.inv(CROSSTALK), atol=0.02)


def test_lcd_pose_is_recovered_from_mirror_captures(rig, tmp_path):
    true_pose = _posed(rig.lcd_to_world, np.array([0.01, -0.008, 0.012, 0.002, -0.0015, 0.001]))
    truth = ms.Rig.from_scene(write_lcd_pose(SCENE, tmp_path / "moved.xml", true_pose))
    bench, _ = simulated_bench(truth, 256, method="mitsuba", spp=4)
    fit = calibrate_lcd_pose(bench, rig)
    assert fit["cells"] > 300
    assert np.linalg.norm(fit["lcd_to_world"][:3, 3] - true_pose[:3, 3]) < 1e-3
    def rotation(m):
        return m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)

    r = rotation(fit["lcd_to_world"]).T @ rotation(true_pose)
    assert np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))) < 0.5


def test_display_calibration_written_into_the_scene_is_what_the_rig_reads(tmp_path):
    out = write_display_model(SCENE, tmp_path / "s.xml", gamma=2.2, intensity=(2.0, 1.8, 1.5))
    assert ms.Rig.from_scene(out).display.intensity == pytest.approx((2.0, 1.8, 1.5))


def test_camera_calibration_round_trips_through_the_scene_file(tmp_path):
    out = write_camera_calibration(SCENE, tmp_path / "cal.xml", response=Response.gamma(2.0), color_matrix=CROSSTALK)
    response, matrix = read_camera_calibration(out)
    np.testing.assert_allclose(response.log_exposure, Response.gamma(2.0).log_exposure)
    np.testing.assert_allclose(matrix, CROSSTALK)
    assert ms.Rig.from_scene(out).lcd_cells == (32, 32)  # still a valid rig scene
    assert read_camera_calibration(SCENE) == (None, None)
