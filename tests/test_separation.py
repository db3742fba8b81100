"""Specular separation (Eq. 4-5)."""

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import patterns as pt
from mitsvbrdf.nets.nafnet import RATIO_FLOOR, diffuse_ratio

from conftest import flat_material, textured_material


def test_flat_diffuse_material_gives_zero_specular_maps(rig):
    m = flat_material(8, specular=0.0)
    m = ms.SVBRDF(normal=m.normal, diffuse=torch.rand(1, 3, 8, 8), roughness=m.roughness, specular=m.specular)
    pats = pt.colorgrad()
    img = ms.render(m, pats, rig, lobes="diffuse")
    spec = ms.separate_specular(img, pats, rig)
    scale = (img.abs().max() * ms.diffuse_irradiance(pats, rig, 8).abs().max()).item()
    assert spec.shape == (1, 10, 3, 8, 8)
    assert spec.abs().max().item() <= 1e-6 * scale


def test_flat_diffuse_material_with_decay_still_cancels(rig):
    r = rig.with_display(decay_cos_power=2.0, decay_gradient=(-0.5, 0.2))
    m = flat_material(8, specular=0.0)
    pats = pt.monograd()
    img = ms.render(m, pats, r, lobes="diffuse")
    spec = ms.separate_specular(img, pats, r)
    scale = (img.abs().max() * ms.diffuse_irradiance(pats, r, 8).abs().max()).item()
    assert spec.abs().max().item() <= 1e-6 * scale


def test_glossy_material_leaves_specular_signal(rig):
    pats = pt.colorgrad()
    m = textured_material(8, roughness=(0.1, 0.3))
    img = ms.render(m, pats, rig)
    spec = ms.separate_specular(img, pats, rig)
    scale = (img.abs().max() * ms.diffuse_irradiance(pats, rig, 8).abs().max()).item()
    assert spec.abs().max().item() > 1e-2 * scale


def test_irradiance_of_a_uniform_pattern_is_the_form_factor(rig):
    ld = ms.diffuse_irradiance(pt.uniform(), rig, 4)
    white = ms.render(flat_material(4, diffuse=1.0, specular=0.0), pt.uniform(), rig, lobes="diffuse")
    torch.testing.assert_close(ld, white[0], rtol=1e-5, atol=0)


def test_unbatched_images_and_pair_order(rig):
    pats = pt.monograd()[:3]
    img = ms.render(flat_material(4), pats, rig)[0]
    spec = ms.separate_specular(img, pats, rig)
    ld = ms.diffuse_irradiance(pats, rig, 4)
    assert spec.shape == (3, 3, 4, 4)
    torch.testing.assert_close(spec[1], img[0] * ld[2] - img[2] * ld[0])


def test_mismatched_image_and_pattern_counts_are_a_clear_error(rig):
    with pytest.raises(ValueError, match="patterns"):
        ms.separate_specular(torch.zeros(1, 3, 3, 4, 4), pt.monograd(), rig)


def test_diffuse_ratio_of_a_flat_lambertian_material_is_its_log_albedo_anywhere_under_the_lcd(rig):
    # log((kd L + f) / (L + f)) differs from log kd by at most f / (kd L): the bound per texel
    kd = 0.1 + 0.8 * torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(3))
    m = flat_material(16, specular=0.0)
    m = ms.SVBRDF(normal=m.normal, diffuse=kd, roughness=m.roughness, specular=m.specular)
    pats = pt.monograd()
    img = ms.render(m, pats, rig, lobes="diffuse")
    ld = ms.diffuse_irradiance(pats, rig, 16)
    r = diffuse_ratio(img, ld)
    bound = RATIO_FLOOR / (kd[:, None] * ld[None]) + 1e-5
    assert ((r - kd.log()[:, None]).abs() <= bound).all()
    assert (bound < 0.001).float().mean() > 0.9  # and tight on most texels
