"""The reference renderer: exact where closed forms exist, right in the mirror limit, differentiable."""

import math

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import patterns as pt
from mitsvbrdf.render import QuadratureSettings

from conftest import flat_material, textured_material


def _form_factor(rig, res, k=500):
    """Point-to-rectangle form factor by a dense float64 midpoint rule (independent of the library)."""
    x = rig.surface_points(res).reshape(-1, 3).double()
    c = torch.tensor(rig.corners_np())
    g = (torch.arange(k, dtype=torch.float64) + 0.5) / k
    v, u = torch.meshgrid(g, g, indexing="ij")
    y = c[0] + u.reshape(-1, 1) * (c[1] - c[0]) + v.reshape(-1, 1) * (c[3] - c[0])
    area = torch.linalg.norm(torch.linalg.cross(c[1] - c[0], c[3] - c[0]))
    nl = torch.tensor(rig.lcd_normal_np())
    out = []
    for xi in x:
        d = y - xi
        d2 = (d * d).sum(-1)
        w = d / d2.sqrt()[:, None]
        out.append((w[:, 2] * (-(w @ nl)) / d2).sum() * area / k ** 2 / math.pi)
    return torch.stack(out).reshape(res, res)


def test_white_lambertian_plane_under_uniform_light_equals_radiance_times_form_factor(rig):
    radiance = 0.7
    img = ms.render(flat_material(8, diffuse=1.0, specular=0.0), pt.uniform(value=radiance), rig, lobes="diffuse")
    ff = _form_factor(rig, 8)
    rel = img[0, 0].double() / (radiance * ff) - 1
    assert rel.abs().max() < 1e-3


def _mirror_cell(rig, res):
    x = rig.surface_points(res).reshape(-1, 3)
    wo = rig.view_directions(res).reshape(-1, 3)
    wi = wo * torch.tensor([-1.0, -1.0, 1.0])
    g = rig.lcd_geometry()
    t = ((g.origin - x) @ g.normal) / (wi @ g.normal)
    rel = x + t[:, None] * wi - g.origin
    u = (rel @ g.edge_u / g.edge_u.dot(g.edge_u)) * 32
    v = (rel @ g.edge_v / g.edge_v.dot(g.edge_v)) * 32
    interior = ((u % 1 - 0.5).abs() < 0.25) & ((v % 1 - 0.5).abs() < 0.25)
    return v.long() * 32 + u.long(), interior, wo


@pytest.mark.parametrize("r", [0.01, 0.005, 0.001])
def test_specular_image_converges_to_fresnel_times_mirror_cell_radiance(rig, r):
    res, ks = 16, 0.3
    pats = pt.random(n=2, seed=1)
    img = ms.render(flat_material(res, specular=ks, roughness=r), pats, rig, lobes="specular")[0]
    cell, interior, wo = _mirror_cell(rig, res)
    cos = wo[:, 2]
    fresnel = ks + (1 - ks) * torch.exp2((-5.55473 * cos - 6.98316) * cos)
    k = max(r * r, ms.ALPHA_MIN) / 2
    g = (cos / (cos * (1 - k) + k)) ** 2
    want = (fresnel * g)[None, None] * pats.reshape(2, 3, -1)[:, :, cell]
    got = img.reshape(2, 3, -1)
    err = (got - want)[:, :, interior].abs()
    # GGX tails put ~1e-3 of the mass of a texel whose mirror point is 1/4 cell from an edge into
    # the neighbouring cell (physics, not quadrature error).
    assert err.max() < 2e-3 * want.max(), err.max() / want.max()


def test_values_and_gradients_are_finite_at_roughness_0_001(rig):
    m = textured_material(8, roughness=(0.0, 0.001))
    for t in (m.normal, m.diffuse, m.roughness, m.specular):
        t.requires_grad_(True)
    pats = pt.random(n=2, seed=0).requires_grad_(True)
    img = ms.render(m, pats, rig)
    assert torch.isfinite(img).all()
    img.square().sum().backward()
    for t in (m.normal, m.diffuse, m.roughness, m.specular, pats):
        assert torch.isfinite(t.grad).all()
    assert pats.grad.abs().sum() > 0


def test_grazing_normals_give_finite_values_and_gradients(rig):
    n = torch.tensor([math.sin(math.radians(89.9)), 0.0, math.cos(math.radians(89.9))])
    m = flat_material(4, normal=tuple(n.tolist()), roughness=0.2)
    m.normal.requires_grad_(True)
    img = ms.render(m, pt.uniform(), rig)
    img.sum().backward()
    assert torch.isfinite(img).all() and torch.isfinite(m.normal.grad).all()


def test_image_is_linear_in_the_radiance_of_the_patterns(rig):
    m = textured_material(6)
    a, b = pt.random(n=1, seed=1), pt.random(n=1, seed=2)
    ia, ib, iab = (ms.render(m, p, rig) for p in (a, b, 0.5 * (a + b)))
    torch.testing.assert_close(iab, 0.5 * (ia + ib), rtol=1e-5, atol=1e-7)


def test_black_pattern_renders_black(rig):
    assert (ms.render(textured_material(4), pt.uniform(value=0.0), rig) == 0).all()


def test_pattern_gradient_matches_finite_differences(rig):
    m = textured_material(6)
    p = pt.random(n=1, seed=5).double().float()
    p.requires_grad_(True)
    w = torch.rand(1, 1, 3, 6, 6, generator=torch.Generator().manual_seed(0))
    loss = lambda q: (ms.render(m, q, rig) * w).sum()
    (g,) = torch.autograd.grad(loss(p), p)
    idx = (0, 1, 13, 9)
    e = torch.zeros_like(p)
    e[idx] = 0.05
    with torch.no_grad():
        hi, lo = loss((p + e).clamp(0, 1)), loss((p - e).clamp(0, 1))
        step = ((p + e).clamp(0, 1) - (p - e).clamp(0, 1))[idx]
        fd = (hi - lo) / step
    # float32 losses: each sum carries ~eps * |sum| of rounding (summation order depends on the
    # thread count), which the difference quotient divides by the step.
    rounding = 4 * torch.finfo(torch.float32).eps * (hi.abs() + lo.abs()).item() / step.item()
    assert abs(g[idx].item() - fd.item()) <= 1e-3 * abs(fd.item()) + rounding


def test_roughness_gradient_matches_finite_differences_for_a_rough_texel(rig):
    m = textured_material(4, roughness=(0.4, 0.6))
    pats = pt.monograd()[1:2]
    r = m.roughness.detach().clone().requires_grad_(True)

    def loss(rr):
        return ms.render(ms.SVBRDF(normal=m.normal, diffuse=m.diffuse, roughness=rr, specular=m.specular), pats, rig).sum()

    (g,) = torch.autograd.grad(loss(r), r)
    e = torch.zeros_like(r)
    e[0, 0, 1, 2] = 1e-2
    with torch.no_grad():
        fd = (loss(r + e) - loss(r - e)) / 2e-2
    assert abs(g[0, 0, 1, 2].item() - fd.item()) <= 2e-3 * abs(fd.item())


def test_per_material_patterns_render_each_material_with_its_own(rig):
    m1, m2 = textured_material(4, seed=1), textured_material(4, seed=2)
    both = ms.SVBRDF.cat([m1, m2])
    p1, p2 = pt.random(n=2, seed=1), pt.random(n=2, seed=2)
    img = ms.render(both, torch.stack([p1, p2]), rig)
    torch.testing.assert_close(img[0], ms.render(m1, p1, rig)[0])
    torch.testing.assert_close(img[1], ms.render(m2, p2, rig)[0])


def test_diffuse_and_specular_lobes_add_up_to_both(rig):
    m = textured_material(4)
    p = pt.monograd()
    torch.testing.assert_close(ms.render(m, p, rig), ms.render(m, p, rig, lobes="diffuse") + ms.render(m, p, rig, lobes="specular"))


def test_emission_decay_is_modelled_only_when_the_scene_asks(rig):
    m = flat_material(4, diffuse=1.0, specular=0.0)
    plain = ms.render(m, pt.uniform(), rig, lobes="diffuse")
    cos_decay = ms.render(m, pt.uniform(), rig.with_display(decay_cos_power=2.0), lobes="diffuse")
    ramp = ms.render(m, pt.uniform(), rig.with_display(decay_gradient=(-1.0, 0.0)), lobes="diffuse")
    assert (cos_decay < plain).all()
    # A ramp falling along u (towards +x) darkens the right of the sample more than its left.
    ratio = (ramp / plain)[0, 0, 0]
    assert (ratio[:, -1] < ratio[:, 0]).all()


def test_denser_quadrature_changes_a_glossy_render_little(rig):
    m = textured_material(6, roughness=(0.1, 0.4))
    p = pt.random(n=1, seed=3)
    a = ms.render(m, p, rig)
    b = ms.render(m, p, rig, settings=QuadratureSettings().denser())
    assert ((a - b).norm() / b.norm()) < 5e-3


def test_unknown_method_is_a_clear_error(rig):
    with pytest.raises(ValueError, match="unknown render method"):
        ms.render(flat_material(4), pt.uniform(), rig, method="raytrace")
