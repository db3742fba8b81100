"""The BRDF is exactly the formula of docs/conventions.md, physically sane, and finite at the extremes."""

import math

import numpy as np
import pytest
import torch

from mitsvbrdf.brdf import ALPHA_MIN, brdf


def _sph(theta, phi):
    return torch.stack([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi), torch.cos(theta)], -1)


def _design_formula(n, l, v, kd, ks, r):
    """The formula, written literally in float64 numpy (independent of the library's algebra)."""
    a = max(r * r, ALPHA_MIN)
    h = (l + v) / np.linalg.norm(l + v)
    nh, nl, nv, vh = n @ h, n @ l, n @ v, v @ h
    D = a * a / (math.pi * (nh * nh * (a * a - 1) + 1) ** 2)
    k = a / 2
    G = nl / (nl * (1 - k) + k) * nv / (nv * (1 - k) + k)
    F = ks + (1 - ks) * 2 ** ((-5.55473 * vh - 6.98316) * vh)
    return kd * (1 - ks) / math.pi + D * G * F / (4 * nl * nv)


def test_matches_design_formula_on_random_inputs():
    rng = np.random.default_rng(1)
    for _ in range(200):
        n = np.array([0, 0, 1.0]) + rng.normal(size=3) * 0.3
        n /= np.linalg.norm(n)
        l, v = (_sph(torch.tensor(rng.uniform(0, 1.4)), torch.tensor(rng.uniform(0, 6.28))).numpy() for _ in range(2))
        if n @ l <= 0.05 or n @ v <= 0.05:
            continue
        kd, ks, r = rng.uniform(0, 1, 3), rng.uniform(0, 1, 3), rng.uniform(0.05, 1)
        want = _design_formula(n, l, v, kd, ks, r)
        got = brdf(*(torch.tensor(a, dtype=torch.float32) for a in (n, l, v, kd, ks)),
                   torch.tensor([r], dtype=torch.float32)).double().numpy()
        np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6)


def test_is_reciprocal():
    g = torch.Generator().manual_seed(0)
    wi = _sph(torch.rand(500, generator=g) * 1.5, torch.rand(500, generator=g) * 6.28)
    wo = _sph(torch.rand(500, generator=g) * 1.5, torch.rand(500, generator=g) * 6.28)
    n = torch.tensor([0.1, -0.2, 1.0]).div(torch.tensor([0.1, -0.2, 1.0]).norm()).expand(500, 3)
    kd, ks, r = torch.rand(500, 3, generator=g), torch.rand(500, 3, generator=g), torch.rand(500, 1, generator=g)
    torch.testing.assert_close(brdf(n, wi, wo, kd, ks, r), brdf(n, wo, wi, kd, ks, r), rtol=1e-5, atol=1e-6)


def test_is_nonnegative_and_zero_below_the_horizon():
    g = torch.Generator().manual_seed(1)
    wi = torch.nn.functional.normalize(torch.randn(2000, 3, generator=g), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(2000, 3, generator=g), dim=-1)
    n = torch.tensor([0.0, 0.0, 1.0]).expand(2000, 3)
    f = brdf(n, wi, wo, torch.rand(2000, 3, generator=g), torch.rand(2000, 3, generator=g),
             torch.rand(2000, 1, generator=g))
    assert (f >= 0).all()
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert (f[below] == 0).all() and (f[~below] > 0).all()


@pytest.mark.parametrize("r", [0.001, 0.01, 0.1, 0.5, 1.0])
def test_specular_albedo_is_at_most_one(r):
    """White furnace on the specular lobe with ks = 1 (F = 1): int f cos dw <= 1 for every view."""
    nt, nphi = 1500, 64
    t = (torch.arange(nt, dtype=torch.float64) + 0.5) / nt * (math.pi / 2)
    p = (torch.arange(nphi, dtype=torch.float64) + 0.5) / nphi * 2 * math.pi
    tt, pp = torch.meshgrid(t, p, indexing="ij")
    wi = _sph(tt, pp).reshape(-1, 3)
    dw = (torch.sin(tt) * (math.pi / 2 / nt) * (2 * math.pi / nphi)).reshape(-1, 1)
    n = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    for theta_o in (0.0, 0.5, 1.0, 1.3, 1.5, 1.569):
        wo = _sph(torch.tensor(theta_o, dtype=torch.float64), torch.tensor(0.0, dtype=torch.float64)).reshape(1, 3)
        one = torch.ones(1, 3, dtype=torch.float64)
        f = brdf(n, wi, wo, one * 0, one, torch.tensor([[r]], dtype=torch.float64), lobes="specular", cosine=True)
        albedo = (f[:, 0:1] * dw).sum().item()
        # Narrow lobes are under-resolved by this grid (albedo then reads low), never high.
        assert albedo <= 1.0 + 2e-3, (r, theta_o, albedo)


def test_diffuse_lobe_albedo_is_kd_times_one_minus_ks():
    n = torch.tensor([[0.0, 0.0, 1.0]])
    wo = _sph(torch.tensor(0.7), torch.tensor(0.0)).reshape(1, 3)
    tt, pp = torch.meshgrid((torch.arange(400) + 0.5) / 400 * math.pi / 2, (torch.arange(32) + 0.5) / 32 * 2 * math.pi, indexing="ij")
    wi = _sph(tt, pp).reshape(-1, 3)
    dw = (torch.sin(tt) * (math.pi / 800) * (2 * math.pi / 32)).reshape(-1, 1)
    kd, ks = torch.tensor([[0.8, 0.5, 0.2]]), torch.tensor([[0.1, 0.3, 0.0]])
    f = brdf(n, wi, wo, kd, ks, torch.tensor([[0.5]]), lobes="diffuse", cosine=True)
    torch.testing.assert_close((f * dw).sum(0, keepdim=True), kd * (1 - ks), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("r", [0.001, 0.01, 1.0])
def test_values_and_gradients_are_finite_at_grazing_angles(r):
    theta = torch.tensor([0.0, 1.0, math.radians(89.0), math.radians(89.9), math.pi / 2])
    wi = _sph(theta, torch.zeros(5)).requires_grad_(True)
    wo = _sph(theta.flip(0), torch.full((5,), math.pi)).requires_grad_(True)
    n = torch.tensor([[0.0, 0.0, 1.0]]).expand(5, 3).clone().requires_grad_(True)
    rough = torch.full((5, 1), r, requires_grad=True)
    kd = torch.full((5, 3), 0.5, requires_grad=True)
    ks = torch.full((5, 3), 0.04, requires_grad=True)
    for cosine in (False, True):
        f = brdf(n, wi, wo, kd, ks, rough, cosine=cosine)
        assert torch.isfinite(f).all()
        grads = torch.autograd.grad(f.sum(), (wi, wo, n, rough, kd, ks))
        assert all(torch.isfinite(g).all() for g in grads)


def test_mirror_peak_is_finite_at_smallest_roughness():
    wo = _sph(torch.tensor(0.4), torch.tensor(0.0)).reshape(1, 3)
    wi = wo * torch.tensor([-1.0, -1.0, 1.0])
    f = brdf(torch.tensor([[0.0, 0.0, 1.0]]), wi, wo, torch.zeros(1, 3), torch.ones(1, 3), torch.tensor([[0.0]]),
             lobes="specular")
    assert torch.isfinite(f).all() and f.min() > 1e6


def test_rejects_unknown_lobe_name():
    with pytest.raises(ValueError, match="lobes"):
        brdf(*(torch.ones(1, 3),) * 5, torch.ones(1, 1), lobes="glossy")
