"""Losses: the cs-only MS-SSIM of Eq. 7 and the L1 terms."""


import pytest
import torch

from mitsvbrdf.losses import importance_consistency_loss, inverse_importance_loss, map_l1, ms_ssim_cs, ssim_cs, _window


def _blob(shift=0.0):
    v, u = torch.meshgrid(torch.linspace(0, 1, 32), torch.linspace(0, 1, 32), indexing="ij")
    return torch.exp(-((u - 0.4 - shift) ** 2 + (v - 0.5) ** 2) / 0.02)[None, None]


def test_identical_maps_have_unit_cs_and_zero_loss():
    x = _blob()
    assert float(ms_ssim_cs(x, x)) == pytest.approx(1.0, abs=1e-6)
    # mean of L_0 and four patterns equal to L_pdf: 4/5 of its contrast, cs close to 1
    loss = float(importance_consistency_loss(torch.zeros(3, 32, 32), x.expand(1, 4, 3, 32, 32), x))
    assert loss < 0.03


def test_cs_ignores_the_mean_level():
    x = _blob()
    assert float(ms_ssim_cs(0.3 + 0.5 * x, 0.5 * x)) == pytest.approx(1.0, abs=1e-5)


def test_nearly_flat_patterns_score_low_against_a_structured_lpdf():
    x = _blob()
    assert float(ms_ssim_cs(0.5 + 0.01 * x, x)) < 0.3


def test_cs_decreases_as_structure_departs():
    x = _blob()
    values = [float(ms_ssim_cs(_blob(s), x)) for s in (0.0, 0.05, 0.2)]
    assert values[0] > values[1] > values[2]


def test_cs_is_finite_with_finite_gradients_for_black_patterns():
    black = torch.zeros(1, 1, 32, 32, requires_grad=True)
    v = ms_ssim_cs(black, _blob())
    v.sum().backward()
    assert torch.isfinite(v).all() and torch.isfinite(black.grad).all()


def test_single_scale_cs_matches_a_direct_float64_computation():
    g = torch.Generator().manual_seed(0)
    x, y = torch.rand(1, 1, 9, 9, generator=g, dtype=torch.float64), torch.rand(1, 1, 9, 9, generator=g, dtype=torch.float64)
    w = _window(dtype=torch.float64)[0, 0]
    vals = []
    for i in range(5):
        for j in range(5):
            px, py = x[0, 0, i:i + 5, j:j + 5], y[0, 0, i:i + 5, j:j + 5]
            mx, my = (w * px).sum(), (w * py).sum()
            sx, sy = (w * px * px).sum() - mx ** 2, (w * py * py).sum() - my ** 2
            sxy = (w * px * py).sum() - mx * my
            vals.append((2 * sxy + 0.03 ** 2) / (sx + sy + 0.03 ** 2))
    assert float(ssim_cs(x, y, _window(dtype=torch.float64))) == pytest.approx(float(torch.stack(vals).mean()), rel=1e-10)


def test_consistency_adds_l0_to_the_predicted_patterns():
    lpdf = _blob()
    l0 = lpdf[0].expand(3, 32, 32)  # L_0 carries the structure of L_pdf, the others add contrast
    same = lpdf[:, None].expand(1, 4, 3, 32, 32)
    assert float(importance_consistency_loss(l0, same, lpdf)) < 1e-5
    assert float(importance_consistency_loss(torch.zeros(3, 32, 32), torch.rand(1, 4, 3, 32, 32), lpdf)) > 0.3


def test_l1_losses():
    a, b = torch.zeros(2, 10, 4, 4), torch.full((2, 10, 4, 4), 0.25)
    assert float(map_l1(a, b)) == pytest.approx(0.25)
    n = torch.zeros(1, 3, 4, 4)
    assert float(inverse_importance_loss(n, torch.zeros(1, 1, 4, 4), n + 0.1, torch.ones(1, 1, 4, 4))) == \
        pytest.approx(1.1)


def test_maps_too_small_for_three_scales_are_refused():
    with pytest.raises(ValueError, match="at least 20 cells"):
        ms_ssim_cs(torch.rand(1, 1, 16, 16), torch.rand(1, 1, 16, 16))


