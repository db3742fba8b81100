"""Camera model (against Mitsuba's sensor), rectification onto the texel grid, checkerboard corners,
Zhang's intrinsics calibration, and intrinsics written back into a scene file."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import mitsvbrdf as ms
from mitsvbrdf.capture.camera import (CameraModel, calibrate_intrinsics, checkerboard_image, checkerboard_points,
                                      find_checkerboard_corners, write_camera_intrinsics)
from mitsvbrdf.errors import SceneError
from mitsvbrdf.rig import DEFAULT_SCENE
from mitsvbrdf.scene_xml import lookat_matrix

SCENE = DEFAULT_SCENE
SIZE = (240, 320)  # (H, W) of the small synthetic camera
# A camera with slightly non-square pixels and an off-centre principal point (what calibration finds).
K_TRUE = np.array([[400.0, 0.0, 165.3], [0.0, 403.0, 117.2], [0.0, 0.0, 1.0]])
INNER, SQUARE = (6, 7), 0.014  # inner corners (rows - 1, cols - 1); square side, metres


def _camera(k: np.ndarray = K_TRUE) -> CameraModel:
    return CameraModel(k, lookat_matrix(np.array([0.0, 0.0, 0.35]), np.zeros(3), np.array([0.0, 1.0, 0.0])), SIZE)


def _board(axis, degrees: float, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    m = np.eye(4)
    a = np.asarray(axis, float)
    m[:3, :3] = Rotation.from_rotvec(np.radians(degrees) * a / np.linalg.norm(a)).as_matrix()
    m[:3, 3] = shift
    return m


def _projected_corners(cam: CameraModel, board: np.ndarray) -> np.ndarray:
    obj = checkerboard_points(INNER, SQUARE)
    return cam.project((board @ np.c_[obj, np.ones(len(obj))].T).T[:, :3])


VIEWS = [_board((1, 0, 0), 35, (0.01, 0.0, 0.0)), _board((0, 1, 0), -35, (0.0, 0.01, 0.02)),
         _board((1, 1, 0), 35, (-0.01, 0.0, 0.0)), _board((1, -1, 0.2), -35, (0.0, -0.01, -0.02)),
         _board((0.3, 1, 0), 30, (0.0, 0.0, 0.01)), _board((1, 0.3, 0), -30, (0.005, 0.005, 0.0))]


def _mitsuba_hits(cam: CameraModel, film_pos: np.ndarray) -> np.ndarray:
    """World points on z = 0 hit by Mitsuba's sensor rays through film positions (N, 2) in [0, 1]^2,
    for a Mitsuba perspective sensor built to match ``cam`` (square pixels only)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    h, w = cam.size
    k = cam.K
    sensor = mi.load_dict({
        "type": "perspective", "fov_axis": "x",
        "fov": float(np.degrees(2 * np.arctan(w / 2 / k[0, 0]))),
        "principal_point_offset_x": float(0.5 - k[0, 2] / w),
        "principal_point_offset_y": float(0.5 - k[1, 2] / h),
        "to_world": mi.ScalarTransform4f(cam.camera_to_world.tolist()),
        "film": {"type": "hdrfilm", "width": w, "height": h}})
    hits = []
    for u, v in film_pos:
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(float(u), float(v)), mi.Point2f(0.5, 0.5))
        o, d = np.array(ray.o, float), np.array(ray.d, float)
        hits.append(o - o[2] / d[2] * d)
    return np.array(hits)


@pytest.mark.parametrize("which", ["default rig", "off-centre principal point"])
def test_projection_agrees_with_mitsuba_sensor_rays(which):
    cam = CameraModel.from_rig(ms.Rig.from_scene())
    if which != "default rig":
        k = np.array([[380.0, 0.0, 150.0], [0.0, 380.0, 131.0], [0.0, 0.0, 1.0]])
        cam = CameraModel(k, cam.camera_to_world, SIZE)
    film = np.random.default_rng(0).uniform(0.05, 0.95, size=(20, 2))
    pix = cam.project(_mitsuba_hits(cam, film))
    h, w = cam.size
    assert np.abs(pix - film * [w, h]).max() < 0.01


def test_sample_centre_projects_to_image_centre():
    cam = CameraModel.from_rig(ms.Rig.from_scene())
    h, w = cam.size
    assert np.allclose(cam.project(np.zeros((1, 3)))[0], [w / 2, h / 2], atol=1e-9)


def _smooth_texels(n: int = 64) -> np.ndarray:
    v, u = np.mgrid[0:n, 0:n] / n
    return np.stack([0.5 + 0.4 * np.sin(2 * np.pi * u), 0.5 + 0.4 * np.cos(2 * np.pi * v),
                     0.5 + 0.3 * np.sin(2 * np.pi * (u + v))], -1)


def test_rectify_undoes_view_of_a_smooth_texel_image():
    rig = ms.Rig.from_scene()
    cam = CameraModel.from_rig(rig)
    x = _smooth_texels(64)
    back = cam.rectify(cam.view(x, rig.sample_size), rig.sample_size, 64)
    assert back.shape == x.shape
    assert np.abs(back - x)[2:-2, 2:-2].max() < 0.01
    assert cam.view(x, rig.sample_size)[0, 0].tolist() == [0.0, 0.0, 0.0]  # the corner pixel misses the sample


def test_rectify_raises_when_the_sample_leaves_the_frame():
    rig = ms.Rig.from_scene()
    cam = CameraModel.from_rig(rig)
    frame = np.zeros((*cam.size, 3))
    with pytest.raises(ValueError, match="outside"):
        cam.rectify(frame, 2 * rig.sample_size, 32)  # a 12 cm sample does not fit the view


def test_checkerboard_corners_are_found_to_a_tenth_of_a_pixel():
    cam = _camera()
    for board in VIEWS[:3]:
        # 8 x 8 samples per pixel: with 4 x 4 the rendered edges themselves are off by ~0.1 px.
        img = checkerboard_image(cam, board, (INNER[0] + 1, INNER[1] + 1), SQUARE, supersample=8)
        found = find_checkerboard_corners(img, INNER)
        assert np.abs(found - _projected_corners(cam, board)).max() < 0.1


def test_corner_order_follows_the_board_when_it_is_turned_upside_down():
    cam = _camera()
    board = _board((1, 0, 0), 20) @ _board((0, 0, 1), 180)  # in-plane half turn, then a tilt
    img = checkerboard_image(cam, board, (INNER[0] + 1, INNER[1] + 1), SQUARE)
    # A wrong order would be off by at least a square (~15 px).
    assert np.abs(find_checkerboard_corners(img, INNER) - _projected_corners(cam, board)).max() < 0.2


def test_checkerboard_with_wrong_corner_count_is_rejected():
    cam = _camera()
    img = checkerboard_image(cam, VIEWS[0], (INNER[0] + 1, INNER[1] + 1), SQUARE)
    with pytest.raises(ValueError, match="expected"):
        find_checkerboard_corners(img, (INNER[0] + 1, INNER[1]))


def test_calibration_recovers_intrinsics_from_synthetic_views():
    cam = _camera()
    corners = [find_checkerboard_corners(
        checkerboard_image(cam, b, (INNER[0] + 1, INNER[1] + 1), SQUARE, supersample=8), INNER) for b in VIEWS]
    k, rms = calibrate_intrinsics(corners, checkerboard_points(INNER, SQUARE), SIZE)
    assert abs(k[0, 0] / K_TRUE[0, 0] - 1) < 0.005 and abs(k[1, 1] / K_TRUE[1, 1] - 1) < 0.005
    assert abs(k[0, 2] - K_TRUE[0, 2]) < 1.0 and abs(k[1, 2] - K_TRUE[1, 2]) < 1.0
    assert rms < 0.2


def test_calibration_needs_three_views():
    cam = _camera()
    corners = [_projected_corners(cam, b) for b in VIEWS[:2]]
    with pytest.raises(ValueError, match="at least 3 views"):
        calibrate_intrinsics(corners, checkerboard_points(INNER, SQUARE), SIZE)


def test_intrinsics_written_into_a_scene_are_what_the_rig_reads(tmp_path):
    k = np.array([[401.5, 0.0, 163.0], [0.0, 401.5, 121.5], [0.0, 0.0, 1.0]])
    out = write_camera_intrinsics(SCENE, tmp_path / "cam.xml", k, SIZE)
    rig = ms.Rig.from_scene(out)
    assert rig.film_size == SIZE
    again = CameraModel.from_rig(rig)
    assert np.allclose(again.K, k, atol=1e-6)
    assert np.allclose(again.camera_to_world, ms.Rig.from_scene(SCENE).camera_to_world)
    assert "The default capture rig" in out.read_text()


def test_writing_intrinsics_needs_a_perspective_sensor(tmp_path):
    bare = tmp_path / "bare.xml"
    bare.write_text('<scene version="3.0.0"><integrator type="path"/></scene>\n')
    with pytest.raises(SceneError, match="perspective"):
        write_camera_intrinsics(bare, tmp_path / "out.xml", K_TRUE, SIZE)
