"""The Mitsuba plugins (lcd emitter, svbrdf_ggx BSDF, importance integrator) and render(method="mitsuba"):
the BSDF, bad input, and the scene camera's path; the estimators are specified in
tests/test_integrator_options.py.

All on the CPU (llvm_ad_rgb) at 8-16 px; skipped when no libLLVM >= 16 is available.
"""

import math
import subprocess
import sys

import numpy as np
import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import backend
from mitsvbrdf import patterns as pt
from mitsvbrdf.errors import PatternError, SceneError
from mitsvbrdf.rig import DEFAULT_SCENE

from conftest import flat_material

pytestmark = pytest.mark.mitsuba
if backend.find_libllvm() is None:  # pragma: no cover - depends on the machine
    pytest.skip("no libLLVM >= 16 for the LLVM backend", allow_module_level=True)

SCENE = DEFAULT_SCENE


@pytest.fixture(scope="module")
def mi():
    import mitsvbrdf_plugins
    return mitsvbrdf_plugins.register("llvm_ad_rgb")


# ---- the BSDF ---------------------------------------------------------------------------------

def test_bsdf_eval_matches_the_torch_brdf(mi):
    import drjit as dr
    g = np.random.default_rng(0)
    n_pts = 500
    def sph(t, p):
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    wi = sph(g.uniform(0, 1.5, n_pts), g.uniform(0, 6.3, n_pts))
    wo = sph(g.uniform(0, 1.5, n_pts), g.uniform(0, 6.3, n_pts))
    for normal, kd, ks, r in [((0, 0, 1), (0.7, 0.4, 0.2), (0.04, 0.05, 0.06), 0.3),
                              ((0.3, -0.2, 0.93), (0.1, 0.9, 0.5), (0.9, 0.6, 0.3), 0.05),
                              ((0, 0, 1), (0.5, 0.5, 0.5), (0.5, 0.5, 0.5), 1.0)]:
        bsdf = mi.load_dict({"type": "svbrdf_ggx", "normal": mi.ScalarColor3f(normal),
                             "diffuse": mi.ScalarColor3f(kd), "specular": mi.ScalarColor3f(ks), "roughness": r})
        si = dr.zeros(mi.SurfaceInteraction3f, n_pts)
        si.wi = mi.Vector3f(wi.T.astype(np.float32))
        si.uv = mi.Point2f(0.5, 0.5)
        got = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T.astype(np.float32)))).T
        nn = torch.tensor(normal, dtype=torch.float32)
        want = ms.brdf(nn / nn.norm(), torch.tensor(wo, dtype=torch.float32), torch.tensor(wi, dtype=torch.float32),
                       torch.tensor(kd), torch.tensor(ks), torch.tensor([r]), cosine=True).numpy()
        # Near the peak of a lobe of width alpha, a half vector rounded to float32 (eps per
        # component) moves D by ~eps / alpha relative: the two implementations round differently.
        alpha = max(r * r, 1e-4)
        rtol = 1e-5 + 4 * np.finfo(np.float32).eps / alpha
        np.testing.assert_allclose(got, want, rtol=rtol, atol=1e-5 * max(1.0, np.abs(want).max()))


# Mitsuba's chi-square grid must resolve the lobe: 301 x 150 cells for alpha = 0.0025 (r = 0.05).
# At grazing incidence that lobe is narrower than any affordable grid (the trapezoid rule then
# lands on its ridge and overestimates), so grazing is tested at r = 0.3 and 1.0.
@pytest.mark.parametrize("roughness,theta_deg,res,ires", [
    (0.05, 10.0, 301, 16), (0.3, 10.0, 201, 8), (1.0, 10.0, 201, 8), (0.3, 80.0, 201, 8), (1.0, 85.0, 201, 8)])
def test_bsdf_sampling_passes_the_chi_square_test(mi, roughness, theta_deg, res, ires):
    t = math.radians(theta_deg)
    sample, pdf = mi.chi2.BSDFAdapter(
        "svbrdf_ggx", f'<float name="roughness" value="{roughness}"/><rgb name="diffuse" value="0.5"/>'
                      '<rgb name="specular" value="0.3"/>', wi=[math.sin(t), 0, math.cos(t)])
    chi2 = mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample, pdf_func=pdf,
                                 sample_dim=3, sample_count=1_000_000, res=res, ires=ires)
    assert chi2.run(), chi2.messages


# ---- the integrator's MIS weight ---------------------------------------------------------------

def test_mis_weight_is_the_power_heuristic(mi):
    from mitsvbrdf_plugins.importance_integrator import mis_weight
    w = np.array(mis_weight(mi.Float([1.0, 3.0, 0.0]), mi.Float([2.0, 1.0, 5.0])))
    np.testing.assert_allclose(w, [1 / 5, 9 / 10, 0.0], rtol=1e-6)


def test_mis_weight_is_zero_where_the_power_heuristic_is_not_finite(mi):
    """Both pdfs 0 (0/0) or an infinite one (inf/inf) must give 0, not NaN, as Mitsuba's mis_weight."""
    from mitsvbrdf_plugins.importance_integrator import mis_weight
    inf = float("inf")
    w = np.array(mis_weight(mi.Float([0.0, inf, inf]), mi.Float([0.0, 1.0, inf])))
    assert w.tolist() == [0.0, 0.0, 0.0]


# Agreement with the reference, one pass for all patterns and materials, kernel reuse, gradients
# and the extremes grid are specified for every estimator of the integrator (the default
# included) in tests/test_integrator_options.py.


# ---- bad input ---------------------------------------------------------------------------------

def test_bad_patterns_are_clear_errors(rig):
    m = flat_material(4)
    with pytest.raises(PatternError, match="32x32-cell"):
        ms.render(m, torch.ones(1, 3, 8, 8), rig, method="mitsuba", spp=1)
    with pytest.raises(PatternError, match="float32"):
        ms.render(m, torch.ones(1, 3, 32, 32, dtype=torch.float64), rig, method="mitsuba", spp=1)
    with pytest.raises(PatternError, match="device"):
        ms.render(m, torch.ones(1, 3, 32, 32, device="meta"), rig, method="mitsuba", spp=1)


def test_mismatched_map_sizes_are_a_clear_error(mi):
    with pytest.raises(Exception, match="differ in size"):
        mi.load_dict({"type": "svbrdf_ggx", "diffuse": mi.TensorXf(np.zeros((4, 4, 3), np.float32)),
                      "specular": mi.TensorXf(np.zeros((8, 8, 3), np.float32))})


def test_scene_with_an_unknown_plugin_is_a_clear_error(rig, tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text(SCENE.read_text().replace('<integrator type="importance"/>', '<integrator type="nonesuch"/>'))
    with pytest.raises(SceneError, match="bad.xml"):
        ms.render(flat_material(4), pt.uniform(), ms.Rig.from_scene(path), method="mitsuba", spp=1)


def test_scene_with_an_unknown_parameter_is_a_clear_error(rig, tmp_path):
    path = tmp_path / "typo.xml"
    path.write_text(SCENE.read_text().replace('<float name="intensity" value="1.0"/>',
                                              '<float name="intensity" value="1.0"/><float name="intensty" value="2"/>'))
    with pytest.raises(SceneError, match="intensty"):
        ms.render(flat_material(4), pt.uniform(), ms.Rig.from_scene(path), method="mitsuba", spp=1)


def _scene_with(mi, tmp_path, tag: str, plugin: str, replacement: str):
    """The default rig's scene with its ``<tag type="plugin">`` element replaced, loaded."""
    text = SCENE.read_text()
    start = text.index(f'<{tag} type="{plugin}"')
    end = text.index(f"</{tag}>", start) + len(f"</{tag}>")
    path = tmp_path / "scene.xml"
    path.write_text(text[:start] + replacement + text[end:])
    return mi.load_file(str(path), resolution=4)


def test_scene_without_an_lcd_emitter_is_a_clear_error(mi, tmp_path):
    scene = _scene_with(mi, tmp_path, "emitter", "lcd", '<emitter type="area"><rgb name="radiance" value="1"/></emitter>')
    with pytest.raises(ValueError, match=r"one emitter of type 'lcd', found 0 among its emitters \(AreaLight\)"):
        scene.integrator().lcd(scene)


def test_scene_without_an_svbrdf_ggx_bsdf_is_a_clear_error(mi, tmp_path):
    scene = _scene_with(mi, tmp_path, "bsdf", "svbrdf_ggx", '<bsdf type="diffuse"/>')
    with pytest.raises(ValueError, match=r"one shape with a BSDF of type 'svbrdf_ggx', found 0 .*SmoothDiffuse"):
        scene.integrator().render_texels(scene, (4, 4), 1, 0)


def test_scene_with_another_integrator_is_a_clear_error(tmp_path):
    path = tmp_path / "direct.xml"
    path.write_text(SCENE.read_text().replace('<integrator type="importance"/>', '<integrator type="direct"/>'))
    with pytest.raises(SceneError, match='integrator must be type="importance"'):
        ms.render(flat_material(4), pt.uniform(), ms.Rig.from_scene(path), method="mitsuba", spp=1)


def test_plugin_class_of_an_unknown_name_is_a_clear_error(mi):
    import mitsvbrdf_plugins
    with pytest.raises(ValueError, match="unknown mitsvbrdf plugin 'area'.*lcd, svbrdf_ggx, importance"):
        mitsvbrdf_plugins.plugin_class("area")


def test_a_variant_keeps_its_plugin_classes_when_the_modules_are_reloaded_for_another():
    """register() reloads the plugin modules for each new variant; scenes of a variant registered
    before must still construct, and be recognised as, that variant's classes. In a subprocess:
    the reload must not leak into the other tests."""
    code = ("import mitsvbrdf as ms, mitsvbrdf_plugins as mp\n"
            "from mitsvbrdf.patterns import uniform\n"
            "mi = mp.register('llvm_ad_rgb')\n"
            "mp._load_classes()  # what registering another variant does to the modules\n"
            "m = ms.SVBRDF.constant(normal=(0, 0, 1), diffuse=0.5, roughness=0.5, specular=0.04, size=2)\n"
            f"img = ms.render(m, uniform(), ms.Rig.from_scene({str(SCENE)!r}), method='mitsuba', spp=1)\n"
            "print(tuple(img.shape), bool(img.isfinite().all()))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "(1, 1, 3, 2, 2) True"


def test_mi_render_through_the_scene_camera_sees_the_lit_sample(mi, rig):
    """The standard SamplingIntegrator path: the centre pixel of the perspective image looks at the
    sample's centre and agrees with the reference at the centre texel (constant material)."""
    scene = mi.load_file(str(SCENE), resolution=9)
    params = mi.traverse(scene)
    params["sample.bsdf.roughness"] = mi.TensorXf(np.full((1, 1, 1), 0.5, np.float32))
    params.update()
    img = np.array(mi.render(scene, spp=4096))
    assert img.shape == (9, 9, 3) and np.isfinite(img).all() and (img >= 0).all()
    m = flat_material(9, diffuse=0.5, specular=0.04, roughness=0.5)
    want = ms.render(m, pt.uniform(), rig)[0, 0, :, 4, 4].numpy()
    np.testing.assert_allclose(img[4, 4], want, rtol=0.03)
