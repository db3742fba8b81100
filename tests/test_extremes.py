"""Every renderer stays finite, in value and gradient, at the extremes of the inputs.

The grid (issue 17): roughness 0.001 (below the alpha clamp), 0.7, 0.9, 0.99 and 1; flat normals
and normals tilted 89.9 degrees in four azimuths; a black, a white and a single-cell pattern.
One material holds the whole grid, a (roughness, normal) pair per texel, repeated 4 x 4 times so
that every pair is seen from several places on the sample (the NaN gradients of issue 17 came
from lobe points that graze the LCD's edge, at 1-8 texels of 1024); each renderer renders it once
under the three patterns and is differentiated once.
"""

import math

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.brdf import sample_vndf_local
from mitsvbrdf.render.quadrature import LocalDirections, lobe_share

ROUGHNESS = (0.001, 0.7, 0.9, 0.99, 1.0)
GRAZING = math.radians(89.9)


def _normals() -> list[tuple[float, float, float]]:
    s, c = math.sin(GRAZING), math.cos(GRAZING)
    return [(0.0, 0.0, 1.0), (s, 0.0, c), (-s, 0.0, c), (0.0, s, c), (0.0, -s, c)]


def extremes_material(repeat: int = 4) -> ms.SVBRDF:
    """(1, C, 5 repeat, 5 repeat): row i % 5 has roughness ROUGHNESS[i % 5], column j % 5 the
    normal _normals()[j % 5]."""
    n = torch.tensor(_normals()).T[:, None, :].expand(3, len(ROUGHNESS), -1).repeat(1, repeat, repeat)
    r = torch.tensor(ROUGHNESS)[:, None].expand(-1, len(_normals())).repeat(repeat, repeat)
    size = n.shape[1:]
    return ms.SVBRDF(normal=n[None].clone(), diffuse=torch.full((1, 3, *size), 0.5),
                     roughness=r[None, None].clone(), specular=torch.full((1, 3, *size), 0.04))


def extremes_patterns(h: int, w: int) -> torch.Tensor:
    """Black, white, and one white cell (the centre one) on black: (3, 3, h, w)."""
    p = torch.zeros(3, 3, h, w)
    p[1] = 1.0
    p[2, :, h // 2, w // 2] = 1.0
    return p


RENDERERS = [
    pytest.param(dict(method="reference"), id="reference"),
    pytest.param(dict(method="ltc", mode="exact"), id="ltc-exact"),
    pytest.param(dict(method="ltc", mode="prefiltered"), id="ltc-prefiltered"),
    pytest.param(dict(method="mitsuba", spp=4), id="mitsuba", marks=pytest.mark.mitsuba),
]


@pytest.mark.parametrize("kwargs", RENDERERS)
def test_extremes_grid_has_finite_images_and_gradients(rig, kwargs):
    if kwargs["method"] == "mitsuba":
        from mitsvbrdf import backend
        if backend.find_libllvm() is None:  # pragma: no cover - depends on the machine
            pytest.skip("no libLLVM >= 16 for the LLVM backend")
    m = extremes_material()
    maps = {k: getattr(m, k).clone().requires_grad_(True) for k in ("normal", "diffuse", "roughness", "specular")}
    pats = extremes_patterns(*rig.lcd_cells).requires_grad_(True)
    img = ms.render(ms.SVBRDF(**maps), pats, rig, **kwargs)
    assert torch.isfinite(img).all()
    assert (img[:, 0] == 0).all(), "a black pattern renders black"
    if kwargs["method"] != "mitsuba":
        # deterministic rules of a non-negative integrand; a Monte Carlo estimate with a control
        # variate (an integrator option of the scene file) may dip below 0 and stay unbiased
        assert (img >= 0).all()
    img.square().sum().backward()
    for name, t in [*maps.items(), ("patterns", pats)]:
        assert torch.isfinite(t.grad).all(), f"non-finite gradient w.r.t. {name}"


def test_extremes_grid_has_a_finite_lpdf_in_the_unit_range(rig):
    m = extremes_material()
    lpdf = ms.importance(m.normal, m.roughness, rig)
    assert torch.isfinite(lpdf).all() and lpdf.min() == 0 and lpdf.max() == 1


@pytest.mark.parametrize("omega", [0.0, 1e-20, 1e-3])
def test_lobe_share_has_finite_gradients_down_to_zero_solid_angle(omega):
    # Lobe-rule directions that graze or miss the LCD carry a vanishing solid angle per light
    # point; the weight must go to 0 there with a finite (zero) gradient, not 0 * inf.
    wi = [torch.tensor([0.3, 0.1]), torch.tensor([0.2, 0.0]), torch.tensor([0.9, 0.99])]
    wi = [c.requires_grad_(True) for c in wi]
    wo = (torch.tensor([0.1, 0.1]), torch.zeros(2), torch.tensor([0.99, 0.99]))
    alpha = torch.tensor([0.81, 1.0], requires_grad=True)
    om = torch.full((2,), omega, requires_grad=True)
    share = lobe_share(LocalDirections.from_local(tuple(wi), wo, alpha), om, 2.0)
    grads = torch.autograd.grad(share.sum(), [alpha, om, *wi])
    assert ((share >= 0) & (share <= 1)).all()
    assert all(torch.isfinite(g).all() for g in grads)


def test_lobe_share_is_the_documented_weight():
    d = LocalDirections.from_local((torch.tensor([0.3]), torch.tensor([0.2]), torch.tensor([0.9])),
                                   (torch.tensor([0.1]), torch.zeros(1), torch.tensor([0.99])), torch.tensor([0.05]))
    omega, window = torch.tensor([1e-4]), 2.0
    l2 = d.alpha ** 2 + d.sin2_h
    want = 1.0 / (1.0 + (l2 / (window ** 2 * omega / (4 * d.o_dot_h))) ** 2)
    torch.testing.assert_close(lobe_share(d, omega, window), want, rtol=1e-6, atol=0)


@pytest.mark.parametrize("u2", [0.0, 0.5, 1.0 - 2.0 ** -24])
def test_visible_normal_warp_has_finite_gradients_at_the_ends_of_the_unit_square(u2):
    # u2 = 0 puts the cap point at its pole, where sqrt(1 - z^2) has an infinite derivative.
    wo = torch.tensor([[0.3, 0.0, math.sqrt(1 - 0.09)]], requires_grad=True)
    alpha = torch.tensor([0.9], requires_grad=True)
    h = sample_vndf_local(wo, alpha, torch.tensor([0.25]), torch.tensor([u2]))
    g = torch.autograd.grad(h.sum(), [wo, alpha])
    assert torch.isfinite(h).all() and all(torch.isfinite(x).all() for x in g)
    torch.testing.assert_close(h.norm(dim=-1), torch.ones(1))


@pytest.mark.parametrize("roughness", [0.9, 1.0])
def test_rough_reference_gradients_match_finite_differences(rig, roughness):
    # As test_reference's rough-texel check (same tolerance), in the range where the gradients were
    # NaN. The loss is the perturbed texel's own radiance (no other texel depends on its
    # roughness), so the difference quotient's own error (step^2 truncation, float32 rounding) is
    # ~1e-5 relative; what the tolerance leaves room for is the quadrature's documented omission of
    # lobe points crossing a cell edge (module docstring of mitsvbrdf.render.quadrature).
    m = ms.SVBRDF.constant(roughness=roughness, size=4)
    pats = extremes_patterns(*rig.lcd_cells)[1:2]
    r = m.roughness.detach().clone().requires_grad_(True)

    def loss(rr):
        return ms.render(ms.SVBRDF(normal=m.normal, diffuse=m.diffuse, roughness=rr, specular=m.specular),
                         pats, rig)[..., 1, 2].sum()

    (g,) = torch.autograd.grad(loss(r), r)
    step = 5e-3
    e = torch.zeros_like(r)
    e[0, 0, 1, 2] = step
    with torch.no_grad():
        if roughness < 1:  # central difference
            fd = (loss(r + e) - loss(r - e)) / (2 * step)
        else:  # roughness stops at 1: the one-sided difference of the same (second) order
            fd = (3 * loss(r) - 4 * loss(r - e) + loss(r - 2 * e)) / (2 * step)
    assert torch.isfinite(g).all()
    assert abs(g[0, 0, 1, 2].item() - fd.item()) <= 2e-3 * abs(fd.item())


@pytest.mark.parametrize("roughness", [0.7, 0.9, 1.0])
def test_rough_reference_normal_gradient_matches_finite_differences(rig, roughness):
    # d/d(theta) of the texel's radiance, its normal tilted by theta = 0.3 rad about y; tolerance
    # as in the roughness check above.
    m = ms.SVBRDF.constant(roughness=roughness, size=4)
    pats = extremes_patterns(*rig.lcd_cells)[1:2]
    mask = torch.zeros(1, 1, 4, 4)
    mask[0, 0, 1, 2] = 1.0

    def loss(theta):
        tilted = torch.stack([torch.sin(theta), torch.zeros_like(theta), torch.cos(theta)]).view(1, 3, 1, 1)
        n = m.normal * (1 - mask) + tilted * mask
        return ms.render(ms.SVBRDF(normal=n, diffuse=m.diffuse, roughness=m.roughness, specular=m.specular),
                         pats, rig)[..., 1, 2].sum()

    theta, step = torch.tensor(0.3, requires_grad=True), 5e-3
    (g,) = torch.autograd.grad(loss(theta), theta)
    with torch.no_grad():
        fd = (loss(theta + step) - loss(theta - step)) / (2 * step)
    assert abs(g.item() - fd.item()) <= 2e-3 * abs(fd.item())
