"""L_pdf (Eq. 2-3): right mass, right place, finite everywhere."""

import torch

import mitsvbrdf as ms
from mitsvbrdf.importance import texel_importance

from conftest import flat_material


def _maps(res, r, normal=(0.0, 0.0, 1.0)):
    m = flat_material(res, roughness=r, normal=normal)
    return m.normal, m.roughness


def test_texel_mass_is_the_ndf_fraction_reflected_onto_the_lcd(rig):
    """Compare with an independent Monte Carlo estimate: draw h ~ D(h)(n.h), reflect, count LCD hits."""
    n, r = _maps(4, 0.6)
    k = texel_importance(n[0], r[0], rig)
    mass = k.sum(1)
    alpha = 0.36
    g = torch.Generator().manual_seed(0)
    N = 400_000
    u1, u2 = torch.rand(N, generator=g, dtype=torch.float64), torch.rand(N, generator=g, dtype=torch.float64)
    tan2 = alpha ** 2 * u1 / (1 - u1)
    ct = 1 / torch.sqrt(1 + tan2)
    st = torch.sqrt(1 - ct ** 2)
    h = torch.stack([st * torch.cos(2 * torch.pi * u2), st * torch.sin(2 * torch.pi * u2), ct], -1)
    x = rig.surface_points(4).reshape(-1, 3).double()
    wo = rig.view_directions(4).reshape(-1, 3).double()
    lcd = rig.lcd_geometry(dtype=torch.float64)
    for i in (0, 5, 15):
        wi = 2 * (h @ wo[i])[:, None] * h - wo[i]
        t = ((lcd.origin - x[i]) @ lcd.normal) / (wi @ lcd.normal)
        rel = x[i] + t[:, None] * wi - lcd.origin
        u = rel @ lcd.edge_u / lcd.edge_u.dot(lcd.edge_u)
        v = rel @ lcd.edge_v / lcd.edge_v.dot(lcd.edge_v)
        hit = ((t > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)).double().mean()
        assert abs(mass[i].item() - hit.item()) < 4 * (hit * (1 - hit) / N).sqrt().item() + 1e-4


def test_unnormalised_lpdf_sums_to_the_number_of_texels(rig):
    n, r = _maps(8, 0.3)
    assert abs(ms.importance(n, r, rig, normalize=False).sum().item() - 64) < 1e-3


def test_flat_smooth_material_peaks_at_the_mirror_cell_of_the_centre(rig):
    n, r = _maps(1, 0.02)  # one texel, at the sample's centre
    lp = ms.importance(n, r, rig)[0, 0]
    x = torch.zeros(3)
    wo = torch.nn.functional.normalize(rig.camera_position - x, dim=0)
    wi = wo * torch.tensor([-1.0, -1.0, 1.0])
    g = rig.lcd_geometry()
    t = ((g.origin - x) @ g.normal) / (wi @ g.normal)
    rel = x + t * wi - g.origin
    u, v = rel @ g.edge_u / g.edge_u.dot(g.edge_u), rel @ g.edge_v / g.edge_v.dot(g.edge_v)
    row, col = divmod(int(lp.argmax()), 32)
    # The centre's mirror point may sit on a cell edge: the peak is a cell touching it.
    assert abs(row + 0.5 - v.item() * 32) <= 1 and abs(col + 0.5 - u.item() * 32) <= 1
    assert lp.max() == 1 and lp.min() == 0


def test_peak_moves_with_the_normal(rig):
    lp0 = ms.importance(*_maps(8, 0.1), rig)[0, 0]
    lp1 = ms.importance(*_maps(8, 0.1, normal=(0.08, 0.0, 1.0)), rig)[0, 0]
    c0 = divmod(int(lp0.argmax()), 32)[1]
    c1 = divmod(int(lp1.argmax()), 32)[1]
    assert c1 > c0 + 2  # tilting towards +x moves the mirror directions towards +x on the LCD


def test_distribution_spreads_with_roughness(rig):
    spreads = []
    for r in (0.05, 0.2, 0.5):
        lp = ms.importance(*_maps(8, r), rig, normalize=False)[0, 0]
        p = lp / lp.sum()
        spreads.append(-(p * p.clamp_min(1e-30).log()).sum().item())  # entropy
    assert spreads[0] < spreads[1] < spreads[2]


def test_near_mirror_material_gives_a_sharp_finite_peak(rig):
    for r in (0.01, 0.001, 0.0):
        lp = ms.importance(*_maps(8, r), rig)
        assert torch.isfinite(lp).all() and lp.max() == 1
        assert (lp > 0.5).float().mean() < 0.2


def test_normals_facing_away_from_the_lcd_never_give_nan_or_all_zero(rig):
    lp = ms.importance(*_maps(4, 0.001, normal=(-0.9, 0.0, 0.2)), rig)
    assert torch.isfinite(lp).all() and lp.max() > 0


def test_batched_and_unbatched_inputs_agree(rig):
    n, r = _maps(4, 0.3)
    torch.testing.assert_close(ms.importance(n, r, rig)[0], ms.importance(n[0], r[0], rig))
