"""Novel-lighting re-rendering and the evaluation metrics."""

import math

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.metrics import flat_normal_rmse, image_rmse, image_ssim, lpips_model, map_rmse
from mitsvbrdf.relight import point_light_images, random_point_lights
from mitsvbrdf.viewing import tonemap

from conftest import flat_material, textured_material


def test_point_lights_are_seeded_and_above_the_sample():
    a, b = random_point_lights(10, seed=3), random_point_lights(10, seed=3)
    assert torch.equal(a, b)
    assert not torch.equal(a, random_point_lights(10, seed=4))
    elevation = torch.rad2deg(torch.asin(a[:, 2] / a.norm(dim=1)))
    assert (elevation >= 25.0 - 1e-4).all()
    assert ((a.norm(dim=1) >= 0.15 - 1e-6) & (a.norm(dim=1) <= 0.4 + 1e-6)).all()


def test_point_light_on_a_lambertian_plane_follows_the_inverse_square_cosine_law(rig):
    kd = 0.6
    m = ms.SVBRDF.constant(diffuse=kd, specular=0.0, roughness=1.0, size=4)
    light = torch.tensor([[0.0, 0.0, 0.2]])
    img = point_light_images(m, light, rig, intensity=1.0)
    x = rig.surface_points(4).reshape(-1, 3)
    d = light - x
    r2 = (d * d).sum(1)
    cos = d[:, 2] / r2.sqrt()
    diffuse = kd / math.pi * cos / r2  # the specular lobe at ks = 0 adds a little (Schlick's term > 0)
    got = img[0, 0, 0].reshape(-1)
    assert (got >= diffuse * (1 - 1e-5)).all()
    assert (got <= diffuse * 1.05).all()


def test_point_light_images_are_differentiable_in_the_maps(rig):
    m = textured_material(8).requires_grad_()
    point_light_images(m, random_point_lights(3), rig).sum().backward()
    assert all(t.grad is not None and torch.isfinite(t.grad).all() for t in m.maps().values())


def test_map_rmse_is_zero_for_identical_maps_and_counts_each_map():
    m = textured_material(8)
    z = map_rmse(m, m)
    assert all(float(v.abs().max()) == 0.0 for v in z.values())
    other = ms.SVBRDF(normal=m.normal, diffuse=(m.diffuse + 0.1).clamp(0, 1), roughness=m.roughness, specular=m.specular)
    e = map_rmse(other, m)
    assert float(e["diffuse"]) > 0 and float(e["normal"]) == 0
    assert float(e["average"]) == pytest.approx(float(e["diffuse"]) / 4)


def test_flat_normal_rmse_is_the_normal_rmse_of_a_flat_prediction():
    m = textured_material(8)
    flat = ms.SVBRDF(normal=flat_material(8).normal, diffuse=m.diffuse, roughness=m.roughness, specular=m.specular)
    assert torch.allclose(flat_normal_rmse(m), map_rmse(flat, m)["normal"], rtol=1e-6)
    assert float(flat_normal_rmse(flat)[0]) == 0.0


def test_metrics_refuse_materials_of_a_different_resolution():
    with pytest.raises(ValueError, match="8x8 but the ground truth is 16x16"):
        map_rmse(flat_material(8), flat_material(16))


def test_image_metrics_rank_a_perturbed_rendering_below_the_exact_one(rig):
    gt = textured_material(16, seed=1)
    near = ms.SVBRDF(normal=gt.normal, diffuse=gt.diffuse * 0.9, roughness=gt.roughness, specular=gt.specular)
    far = ms.SVBRDF(normal=gt.normal, diffuse=gt.diffuse * 0.5, roughness=gt.roughness, specular=gt.specular)
    lights = random_point_lights(4)
    g = point_light_images(gt, lights, rig)
    exposure = 1.0 / float(torch.quantile(g.flatten(), 0.99))
    tg = tonemap(g, exposure)
    tn, tf = (tonemap(point_light_images(m, lights, rig), exposure) for m in (near, far))
    assert float(image_rmse(tg, tg)) == 0.0
    assert float(image_rmse(tn, tg)) < float(image_rmse(tf, tg))
    assert float(image_ssim(tg, tg)) == pytest.approx(1.0)
    assert float(image_ssim(tn, tg)) > float(image_ssim(tf, tg))


def test_lpips_is_skipped_with_a_reason_when_unavailable():
    model, why = lpips_model()
    assert (model is None) == bool(why)
