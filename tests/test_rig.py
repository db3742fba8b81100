"""The default rig (mitsvbrdf/scenes/lcd_rig.xml): sizes, the mirror configuration, and clear scene errors."""

import math

import numpy as np
import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.errors import SceneError
from mitsvbrdf.rig import DEFAULT_SCENE

SCENE = DEFAULT_SCENE


def test_default_rig_has_a_9cm_lcd_of_32x32_cells_and_a_256px_camera(rig):
    c = rig.lcd_corners
    assert torch.allclose((c[1] - c[0]).norm(), torch.tensor(0.09), atol=1e-6)
    assert torch.allclose((c[3] - c[0]).norm(), torch.tensor(0.09), atol=1e-6)
    assert rig.lcd_cells == (32, 32) and rig.film_size == (256, 256)


def test_lcd_normal_points_at_the_sample(rig):
    centre = rig.lcd_corners.mean(0)
    assert torch.dot(rig.lcd_normal, -centre / centre.norm()) > 0.99


def _mirror_hits(rig, res=64):
    x = rig.surface_points(res).reshape(-1, 3).double()
    wo = rig.view_directions(res).reshape(-1, 3).double()
    wi = wo * torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64)
    g = rig.lcd_geometry(dtype=torch.float64)
    t = ((g.origin - x) @ g.normal) / (wi @ g.normal)
    rel = x + t[:, None] * wi - g.origin
    return t, rel @ g.edge_u / g.edge_u.dot(g.edge_u), rel @ g.edge_v / g.edge_v.dot(g.edge_v)


def test_every_texel_of_a_flat_mirror_reflects_the_camera_into_the_lcd(rig):
    t, u, v = _mirror_hits(rig)
    assert (t > 0).all()
    margin = 0.003 / 0.09  # at least 3 mm inside the LCD's edges
    assert u.min() > margin and u.max() < 1 - margin and v.min() > margin and v.max() < 1 - margin


def test_mirror_image_keeps_the_texel_grid_orientation(rig):
    """Pattern columns follow texel columns and pattern rows follow texel rows under a mirror."""
    _, u, v = _mirror_hits(rig, 8)
    u, v = u.reshape(8, 8), v.reshape(8, 8)
    assert (u[:, 1:] > u[:, :-1]).all() and (v[1:, :] > v[:-1, :]).all()


def test_camera_sees_the_whole_sample_past_the_lcd(rig):
    cam = rig.camera_position.double()
    x = rig.surface_points(32).reshape(-1, 3).double()
    d = torch.nn.functional.normalize(x - cam, dim=-1)
    half_fov = math.radians(rig.camera_fov / 2)
    angle = torch.acos((d @ torch.tensor(rig.camera_to_world[:3, 2])).clamp(-1, 1))
    assert angle.max() < half_fov
    g = rig.lcd_geometry(dtype=torch.float64)
    t = ((g.origin - cam) @ g.normal) / (d @ g.normal)
    rel = cam + t[:, None] * d - g.origin
    u, v = rel @ g.edge_u / g.edge_u.dot(g.edge_u), rel @ g.edge_v / g.edge_v.dot(g.edge_v)
    blocked = (t > 0) & (t < (x - cam).norm(dim=-1)) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    assert not blocked.any()


def test_surface_points_are_texel_centres_with_row_zero_at_the_top(rig):
    p = rig.surface_points(4)
    s = rig.sample_size
    assert p.shape == (4, 4, 3)
    assert torch.allclose(p[0, 0], torch.tensor([-3 * s / 8, 3 * s / 8, 0.0]))
    assert torch.allclose(p[3, 3], torch.tensor([3 * s / 8, -3 * s / 8, 0.0]))


def test_view_directions_are_unit_and_point_to_the_camera(rig):
    d = rig.view_directions(8)
    torch.testing.assert_close(d.norm(dim=-1), torch.ones(8, 8))
    to_cam = rig.camera_position - rig.surface_points(8)
    torch.testing.assert_close(d, torch.nn.functional.normalize(to_cam, dim=-1))


def test_cell_corners_tile_the_lcd_in_pattern_order(rig):
    cc = rig.lcd_cell_corners()
    c = rig.lcd_corners
    assert cc.shape == (32, 32, 4, 3)
    torch.testing.assert_close(cc[0, 0, 0], c[0])
    torch.testing.assert_close(cc[0, -1, 1], c[1], atol=1e-6, rtol=0)
    torch.testing.assert_close(cc[-1, 0, 3], c[3], atol=1e-6, rtol=0)
    torch.testing.assert_close(rig.lcd_cell_centres()[0, 0], cc[0, 0].mean(0))


def test_display_model_is_linear_without_calibration(rig):
    p = torch.rand(2, 3, 32, 32)
    torch.testing.assert_close(rig.display_radiance(p), p)
    assert not rig.display.has_decay


def test_display_model_applies_gamma_matrix_and_intensity(rig):
    m = ((0.9, 0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.2, 0.8))
    r = rig.with_display(gamma=2.2, color_matrix=m, intensity=(2.0, 1.0, 0.5))
    p = torch.rand(1, 3, 32, 32)
    want = torch.einsum("ij,pjhw->pihw", torch.tensor(m), p ** 2.2) * torch.tensor([2.0, 1.0, 0.5]).view(3, 1, 1)
    torch.testing.assert_close(r.display_radiance(p), want)


def _write(tmp_path, text):
    p = tmp_path / "scene.xml"
    p.write_text(text)
    return p


def test_scene_without_lcd_is_a_clear_error(tmp_path):
    text = SCENE.read_text().replace('type="lcd"', 'type="area"')
    with pytest.raises(SceneError, match="lcd"):
        ms.Rig.from_scene(_write(tmp_path, text))


def test_scene_without_sample_bsdf_is_a_clear_error(tmp_path):
    text = SCENE.read_text().replace('type="svbrdf_ggx"', 'type="diffuse"')
    with pytest.raises(SceneError, match="sample"):
        ms.Rig.from_scene(_write(tmp_path, text))


def test_missing_and_malformed_scene_files_are_clear_errors(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        ms.Rig.from_scene(tmp_path / "nope.xml")
    with pytest.raises(SceneError, match="not a valid XML"):
        ms.Rig.from_scene(_write(tmp_path, SCENE.read_text()[:500]))


def test_lcd_facing_away_is_a_clear_error(tmp_path):
    text = SCENE.read_text().replace('target="0, 0, 0" up="0, -1, 0"', 'target="-0.2, 0, 0.3" up="0, -1, 0"')
    with pytest.raises(SceneError, match="faces away"):
        ms.Rig.from_scene(_write(tmp_path, text))


def test_decay_and_cell_count_come_from_the_scene_file(tmp_path):
    text = SCENE.read_text().replace(
        '<float name="intensity" value="1.0"/>',
        '<float name="intensity" value="1.0"/><float name="decay_cos_power" value="3"/>'
        '<vector name="decay_gradient" x="-0.5" y="0" z="0"/>').replace('name="cells_x" value="32"', 'name="cells_x" value="16"')
    r = ms.Rig.from_scene(_write(tmp_path, text))
    assert r.lcd_cells == (32, 16)
    assert r.display.decay_cos_power == 3.0 and r.display.decay_gradient == (-0.5, 0.0)


def test_scene_xml_transforms_match_mitsuba_semantics():
    """scale then lookat composes as lookat @ scale, and rotate follows the right-hand rule."""
    from mitsvbrdf.scene_xml import _rotation, lookat_matrix
    r = _rotation(np.array([0, 0, 1.0]), 90)
    np.testing.assert_allclose(r[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    m = lookat_matrix(np.array([0, 0, 1.0]), np.zeros(3), np.array([0, 1.0, 0]))
    np.testing.assert_allclose(m[:3, 2], [0, 0, -1])


@pytest.mark.mitsuba
def test_rig_geometry_matches_mitsubas_own_reading_of_the_scene():
    """Mitsuba parses the same file (project plugin types swapped for built-ins) to the same transforms."""
    import re

    from mitsvbrdf import backend
    if backend.find_libllvm() is None:
        pytest.skip("no libLLVM >= 16 on this machine")
    mi = backend.import_mitsuba("llvm_ad_rgb")
    text = SCENE.read_text()
    text = text.replace('type="lcd"', 'type="area"').replace('type="svbrdf_ggx"', 'type="diffuse"')
    text = text.replace('<integrator type="importance"/>', '<integrator type="direct"/>')
    text = re.sub(r'<(integer|float|rgb) name="(cells_x|cells_y|intensity|diffuse|specular|roughness)"[^>]*/>', "", text)
    params = mi.traverse(mi.load_string(text))
    rig = ms.Rig.from_scene(SCENE)
    np.testing.assert_allclose(np.array(params["lcd.to_world"].matrix.numpy()).reshape(4, 4), rig.lcd_to_world, atol=1e-6)
    np.testing.assert_allclose(np.array(params["camera.to_world"].matrix.numpy()).reshape(4, 4), rig.camera_to_world, atol=1e-6)
    sample = np.array(params["sample.to_world"].matrix.numpy()).reshape(4, 4)
    np.testing.assert_allclose(np.diag(sample)[:2], [rig.sample_size / 2] * 2, atol=1e-7)


INTENSITY = '<float name="intensity" value="1.0"/>'
LCD_SCALE = '<scale x="0.045" y="0.045"/>'
CELLS_X = '<integer name="cells_x" value="32"/>'

# (what is broken, the edit of the default scene, words the message must contain)
BROKEN_DISPLAY = [
    ("zero-size LCD", (LCD_SCALE, '<scale x="0" y="0"/>'), "positive size"),
    ("LCD of zero width", (LCD_SCALE, '<scale x="0" y="0.045"/>'), "positive size"),
    ("zero cells", (CELLS_X, '<integer name="cells_x" value="0"/>'), "cells_x"),
    ("fractional cells", (CELLS_X, '<float name="cells_x" value="2.5"/>'), "cells_x"),
    ("zero intensity", (INTENSITY, '<float name="intensity" value="0"/>'), "intensity"),
    ("negative intensity", (INTENSITY, '<float name="intensity" value="-1"/>'), "intensity"),
    ("one dark channel", (INTENSITY, '<rgb name="intensity" value="1, 0, 1"/>'), "intensity"),
    ("NaN intensity", (INTENSITY, '<float name="intensity" value="nan"/>'), "finite"),
    ("zero gamma", (INTENSITY, INTENSITY + '<float name="gamma" value="0"/>'), "gamma"),
    ("negative gamma", (INTENSITY, INTENSITY + '<float name="gamma" value="-2.2"/>'), "gamma"),
    ("NaN in the colour matrix", (INTENSITY, INTENSITY + '<string name="color_matrix" value="1 0 0 0 nan 0 0 0 1"/>'),
     "color_matrix"),
    ("Inf in the colour matrix", (INTENSITY, INTENSITY + '<string name="color_matrix" value="1 0 0 0 1 0 0 0 inf"/>'),
     "color_matrix"),
    ("words in the colour matrix", (INTENSITY, INTENSITY + '<string name="color_matrix" value="one 0 0 0 1 0 0 0 1"/>'),
     "color_matrix"),
    ("negative decay power", (INTENSITY, INTENSITY + '<float name="decay_cos_power" value="-1"/>'), "decay_cos_power"),
    ("infinite translation", ('<scale x="0.03" y="0.03"/>', '<scale x="0.03" y="0.03"/><translate x="inf"/>'),
     "finite"),
    ("float without a number", (INTENSITY, '<float name="intensity" value=""/>'), "expected 1 number"),
    ("zero fov", ('<float name="fov" value="13"/>', '<float name="fov" value="0"/>'), "fov"),
    ("empty film", ('<integer name="width" value="$resolution"/>', '<integer name="width" value="0"/>'), "film"),
]


@pytest.mark.parametrize("edit,words", [pytest.param(e, w, id=i) for i, e, w in BROKEN_DISPLAY])
def test_broken_display_model_or_geometry_is_a_scene_error_naming_the_file(tmp_path, edit, words):
    old, new = edit
    assert old in SCENE.read_text()
    path = _write(tmp_path, SCENE.read_text().replace(old, new, 1))
    with pytest.raises(SceneError, match=words) as e:
        ms.Rig.from_scene(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("change", [dict(intensity=(0.0, 1.0, 1.0)), dict(gamma=0.0), dict(gamma=float("nan")),
                                    dict(color_matrix=((1, 0, 0), (0, float("inf"), 0), (0, 0, 1))),
                                    dict(decay_cos_power=-0.5), dict(decay_gradient=(float("nan"), 0.0))],
                         ids=["intensity", "gamma", "nan-gamma", "matrix", "decay", "gradient"])
def test_display_model_made_in_code_meets_the_same_contract(rig, change):
    with pytest.raises(SceneError, match=next(iter(change))):
        rig.with_display(**change)


@pytest.mark.mitsuba
@pytest.mark.parametrize("params,words", [({"intensity": 0.0}, "intensity"), ({"intensity": -1.0}, "intensity"),
                                          ({"gamma": 0.0}, "gamma"),
                                          ({"color_matrix": "1 0 0 0 nan 0 0 0 1"}, "color_matrix"),
                                          ({"decay_cos_power": -1.0}, "decay_cos_power")])
def test_lcd_plugin_refuses_the_same_display_models(params, words):
    from mitsvbrdf import backend
    if backend.find_libllvm() is None:  # pragma: no cover - depends on the machine
        pytest.skip("no libLLVM >= 16 for the LLVM backend")
    import mitsvbrdf_plugins
    mi = mitsvbrdf_plugins.register("llvm_ad_rgb")
    with pytest.raises(Exception, match=words):
        mi.load_dict({"type": "rectangle", "emitter": {"type": "lcd", **params}})


# ---- windows of the sample (crops that keep their place in the rig) ------------------------------


def test_a_windows_texels_are_that_crop_of_the_whole_grid(rig):
    whole = rig.surface_points(16)
    torch.testing.assert_close(rig.window(16, 4, 8, 8).surface_points(8), whole[4:12, 8:16], rtol=0, atol=1e-9)


def test_a_window_of_a_window_is_the_crop_of_the_crop(rig):
    inner = rig.window(16, 4, 8, 8).window(8, 2, 1, 4)
    torch.testing.assert_close(inner.surface_points(4), rig.surface_points(16)[6:10, 9:13], rtol=0, atol=1e-9)


def test_the_window_of_the_whole_grid_is_the_rig_itself(rig):
    w = rig.window(16, 0, 0, 16)
    np.testing.assert_allclose(w.sample_to_world(), rig.sample_to_world(), rtol=0, atol=1e-15)
    assert w.sample_centre == (0.0, 0.0) and w.sample_size == rig.sample_size


def test_a_window_keeps_camera_lcd_and_display(rig):
    w = rig.window(8, 1, 2, 4)
    assert w.display is rig.display and w.lcd_cells == rig.lcd_cells and w.source == rig.source
    np.testing.assert_array_equal(w.lcd_to_world, rig.lcd_to_world)
    np.testing.assert_array_equal(w.camera_to_world, rig.camera_to_world)


def test_a_windows_texels_are_indexed_in_the_parents_row_major_grid(rig):
    parent, grid, idx = rig.window(16, 4, 8, 8).window_texels(8)
    assert parent is rig and grid == 16
    torch.testing.assert_close(rig.surface_points(16).reshape(-1, 3)[idx],
                               rig.window(16, 4, 8, 8).surface_points(8).reshape(-1, 3), rtol=0, atol=1e-9)


def test_a_window_of_a_window_is_indexed_in_the_first_parents_grid(rig):
    parent, grid, idx = rig.window(16, 4, 8, 8).window(8, 2, 1, 4).window_texels(4)
    assert parent is rig and grid == 16
    torch.testing.assert_close(rig.surface_points(16).reshape(-1, 3)[idx],
                               rig.surface_points(16)[6:10, 9:13].reshape(-1, 3), rtol=0, atol=0)


def test_a_window_shares_no_texels_at_another_resolution_or_once_altered(rig):
    w = rig.window(16, 4, 8, 8)
    assert rig.window_texels(16) is None and w.window_texels(16) is None
    assert w.with_display(decay_cos_power=3.0).window_texels(8) is None


def test_the_scene_files_sample_transform_is_the_rigs(rig):
    np.testing.assert_allclose(rig.sample_to_world(), np.diag([rig.sample_size / 2] * 2 + [1.0, 1.0]), atol=1e-15)


@pytest.mark.parametrize("args", [(16, 9, 0, 8), (16, 0, -1, 8), (16, 0, 0, 17), (16, 0, 0, 0), (16, 0.5, 0, 8),
                                  (16, 0, 0, True)])
def test_a_window_outside_the_grid_is_a_clear_error(rig, args):
    with pytest.raises(ValueError, match="window"):
        rig.window(*args)
