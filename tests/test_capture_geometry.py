"""LCD pose from its reflections in a mirror sample (simulated), written back into a scene."""

import numpy as np
import pytest

import mitsvbrdf as ms
from mitsvbrdf.capture.geometry import _posed, fit_lcd_pose, mirror_points, write_lcd_pose
from mitsvbrdf.rig import DEFAULT_SCENE

SCENE = DEFAULT_SCENE


def _true_pose(rig):
    # the real LCD sits 2 mm and about 1 degree away from where the scene file says
    return _posed(rig.lcd_to_world, np.array([0.012, -0.008, 0.010, 0.002, -0.0015, 0.001]))


def _angle_deg(a, b):
    r = a[:3, :3] / np.linalg.norm(a[:3, :3], axis=0) @ (b[:3, :3] / np.linalg.norm(b[:3, :3], axis=0)).T
    return np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def test_pose_is_recovered_within_a_millimetre_and_half_a_degree(rig):
    truth = _true_pose(rig)
    cells = np.array([(i, j) for i in range(0, 32, 3) for j in range(0, 32, 3)])  # 121 lit cells
    pts = mirror_points(truth, rig.camera_position_np(), cells, rig.lcd_cells)
    pts[:, :2] += np.random.default_rng(0).normal(0, 1e-4, size=(len(pts), 2))  # 0.1 mm spot centroids
    fit = fit_lcd_pose(rig, cells, pts)
    assert np.linalg.norm(fit[:3, 3] - truth[:3, 3]) < 1e-3
    assert _angle_deg(fit, truth) < 0.5
    assert _angle_deg(rig.lcd_to_world, truth) > 0.5  # the nominal pose alone would fail


def test_pose_written_into_a_scene_is_what_the_rig_reads(rig, tmp_path):
    truth = _true_pose(rig)
    out = write_lcd_pose(SCENE, tmp_path / "posed.xml", truth)
    again = ms.Rig.from_scene(out)
    assert np.allclose(again.lcd_to_world, truth, atol=1e-9)
    assert "The default capture rig" in out.read_text()


def test_too_few_cells_are_refused(rig):
    with pytest.raises(ValueError, match=">= 4 lit cells"):
        fit_lcd_pose(rig, np.zeros((3, 2)), np.zeros((3, 3)))
