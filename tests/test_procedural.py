"""Procedural SVBRDF generator: determinism, valid maps, the height -> normal convention, coverage
of the parameter ranges by every family, and the ``materials preview`` command."""

from __future__ import annotations

import math

import pytest
import torch

import mitsvbrdf as ms
from conftest import SAMPLES, needs_samples
from mitsvbrdf.data import procedural, stats
from mitsvbrdf.data.procedural import FAMILIES, family_of, generate, height_to_normal, material
from mitsvbrdf.errors import MaterialError

MAPS = ("normal", "diffuse", "roughness", "specular")


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def coverage_set() -> ms.SVBRDF:
    """108 materials (9 of every family) at 48 px."""
    return generate(108, size=48, seed=0)


# ---- determinism -------------------------------------------------------------------------------


def test_same_seed_gives_identical_maps():
    a, b = generate(12, size=32, seed=7), generate(12, size=32, seed=7)
    for k in MAPS:
        assert torch.equal(getattr(a, k), getattr(b, k)), k


def test_different_seeds_give_different_materials():
    a, b = generate(12, size=32, seed=1), generate(12, size=32, seed=2)
    for i in range(12):
        assert not torch.allclose(a.diffuse[i], b.diffuse[i]) or not torch.allclose(a.normal[i], b.normal[i])


def test_material_i_is_the_same_alone_in_any_batch_and_chunking():
    batch = generate(14, size=32, seed=3)
    other = generate(14, size=32, seed=3, chunk=1)
    for i in (0, 5, 13):
        alone = material(i, size=32, seed=3)
        for k in MAPS:
            torch.testing.assert_close(getattr(alone, k)[0], getattr(batch, k)[i], atol=1e-6, rtol=0)
            torch.testing.assert_close(getattr(other, k)[i], getattr(batch, k)[i], atol=1e-6, rtol=0)
    window = generate(4, size=32, seed=3, start=10)
    torch.testing.assert_close(window.normal, batch.normal[10:14], atol=1e-6, rtol=0)


def test_each_round_of_indices_deals_every_family_once():
    n = len(FAMILIES)
    for r in range(3):
        assert sorted(family_of(i, seed=5) for i in range(r * n, (r + 1) * n)) == sorted(FAMILIES)
    assert [family_of(i, seed=5) for i in range(n)] != [family_of(i, seed=6) for i in range(n)]
    assert {family_of(i, families=["tiles", "fabric"]) for i in range(6)} == {"tiles", "fabric"}


def test_one_material_at_two_resolutions_shows_the_same_structure():
    small, large = generate(12, size=32, seed=4), generate(12, size=128, seed=4)
    down = torch.nn.functional.interpolate(large.diffuse, size=(32, 32), mode="area")
    corr = []
    for i in range(12):
        x, y = small.diffuse[i].flatten(), down[i].flatten()
        if x.std() > 1e-3 and y.std() > 1e-3:
            corr.append(float(torch.corrcoef(torch.stack([x, y]))[0, 1]))
    assert len(corr) >= 8
    assert sorted(corr)[len(corr) // 2] > 0.9 and min(corr) > 0.5


# ---- valid maps ----------------------------------------------------------------------------------


def test_generated_maps_are_valid_svbrdfs_with_unit_normals():
    m = generate(24, size=40, seed=0)
    m.validate()
    assert m.resolution == (40, 40) and m.batch_size == 24
    torch.testing.assert_close(m.normal.norm(dim=1), torch.ones(24, 40, 40), atol=1e-5, rtol=0)
    assert m.roughness.min() >= procedural.ROUGHNESS_MIN - 1e-7 and m.roughness.max() <= 1
    for k in ("diffuse", "specular"):
        assert getattr(m, k).min() >= 0 and getattr(m, k).max() <= 1


def test_device_argument_places_the_maps():
    m = generate(2, size=16, device="cpu")
    assert m.device.type == "cpu"
    if torch.cuda.is_available():
        g = generate(2, size=16, device="cuda")
        assert g.device.type == "cuda"
        torch.testing.assert_close(g.diffuse.cpu(), m.diffuse, atol=1e-4, rtol=0)


def test_threads_argument_restores_torch_setting():
    before = torch.get_num_threads()
    generate(1, size=16, threads=1)
    assert torch.get_num_threads() == before


@pytest.mark.parametrize("kwargs", [dict(n=0), dict(n=1, size=2), dict(n=1, families=["granite"]),
                                    dict(n=1, families=[]), dict(n=1, bump=-1.0), dict(n=1, bump=(0.0, 2.0)),
                                    dict(n=1, bump=(2.0, 1.0)), dict(n=1, bump=(1.0, math.inf)),
                                    dict(n=1, bump=(1.0, 2.0, 3.0)), dict(n=1, bump=True),
                                    dict(n=1, dark_metals=-0.1), dict(n=1, dark_metals=1.5),
                                    dict(n=1, dark_metals=True)])
def test_bad_arguments_raise_material_error(kwargs):
    with pytest.raises(MaterialError):
        generate(**kwargs)


# ---- heights -> normals ----------------------------------------------------------------------------


def test_height_plane_gives_the_tangent_space_normal_with_y_up():
    H = W = 8
    a, b = 0.3, -0.7  # h = a x + b y, x right, y up, in sample units (side 1)
    cols = (torch.arange(W) + 0.5) / W
    rows = (torch.arange(H) + 0.5) / H
    y_up = (0.5 - rows).view(H, 1)
    h = (a * cols.view(1, W) + b * y_up).unsqueeze(0)
    n = height_to_normal(h)
    want = torch.tensor([-a, -b, 1.0]) / math.sqrt(a * a + b * b + 1)
    torch.testing.assert_close(n[0].permute(1, 2, 0), want.expand(H, W, 3), atol=1e-5, rtol=0)


def test_bump_normals_lean_away_from_the_top_of_a_hill():
    yy, xx = torch.meshgrid(torch.arange(16.0), torch.arange(16.0), indexing="ij")
    h = torch.exp(-((xx - 8) ** 2 + (yy - 8) ** 2) / 8).unsqueeze(0) * 0.05
    n = height_to_normal(h)[0]
    assert n[1, 5, 8] > 0.1  # a texel above the hilltop (smaller row) faces up the sample: n_y > 0
    assert n[1, 11, 8] < -0.1
    assert n[0, 8, 11] > 0.1 and n[0, 8, 5] < -0.1  # right of it faces right: n_x > 0


def test_bump_scales_the_relief_from_flat_to_steep():
    flat = generate(12, size=48, seed=2, bump=0.0)
    torch.testing.assert_close(flat.normal[:, 2], torch.ones(12, 48, 48))
    slopes = [float(stats.texel_values(generate(12, size=48, seed=2, bump=s))["slope_deg"].quantile(0.99))
              for s in (0.5, 1.0, 4.0)]
    assert slopes[0] < slopes[1] < slopes[2]
    steep = stats.texel_values(generate(12, size=48, seed=2, bump=4.0))["slope_deg"]
    assert (steep > 60).float().mean() > 1e-3  # steep slopes are reachable


def test_a_bump_range_multiplies_each_material_by_its_own_factor_in_the_range():
    base = generate(8, size=32, seed=3)
    ranged = generate(8, size=32, seed=3, bump=(1.0, 4.0))
    factors = [procedural.bump_factor(i, 3, (1.0, 4.0)) for i in range(8)]
    assert all(1.0 <= f <= 4.0 for f in factors) and len(set(factors)) == 8
    for i, f in enumerate(factors):
        torch.testing.assert_close(ranged.normal[i], generate(1, size=32, seed=3, start=i, bump=f).normal[0])
    torch.testing.assert_close(ranged.diffuse, base.diffuse)  # only the relief changes
    torch.testing.assert_close(ranged.roughness, base.roughness)


def test_a_material_keeps_its_bump_factor_in_any_batch():
    whole = generate(6, size=16, seed=4, bump=(0.5, 3.0))
    part = generate(2, size=16, seed=4, bump=(0.5, 3.0), start=4)
    torch.testing.assert_close(whole.normal[4:], part.normal)


def test_a_degenerate_bump_range_is_its_one_value():
    torch.testing.assert_close(generate(3, size=16, seed=5, bump=(2.0, 2.0)).normal,
                               generate(3, size=16, seed=5, bump=2.0).normal)


def test_dark_metals_scale_only_the_f0_of_pure_metal_texels_by_the_materials_own_factor():
    base = generate(36, size=16, seed=6)
    dark = generate(36, size=16, seed=6, dark_metals=1.0)
    metal = procedural.pure_metal_texels(base.diffuse)
    factors = torch.tensor([procedural.metal_dimming(i, 6, 1.0) for i in range(36)]).view(-1, 1, 1, 1)
    lo, hi = procedural.DARK_METAL_F0
    assert bool(((factors >= lo) & (factors <= hi)).all())
    assert bool(metal.any()), "the stream's first 36 materials hold pure metal texels"
    torch.testing.assert_close(dark.specular, torch.where(metal, base.specular * factors, base.specular))
    for key in ("normal", "diffuse", "roughness"):
        torch.testing.assert_close(getattr(dark, key), getattr(base, key))


def test_no_dark_metals_leaves_the_stream_as_it_was():
    assert procedural.metal_dimming(3, 0, 0.0) == 1.0
    torch.testing.assert_close(generate(12, size=16, seed=7, dark_metals=0.0).specular,
                               generate(12, size=16, seed=7).specular)


def test_dark_metals_darken_about_their_fraction_of_materials():
    n, fraction = 400, 0.25
    darkened = sum(procedural.metal_dimming(i, 0, fraction) != 1.0 for i in range(n))
    sd = math.sqrt(n * fraction * (1 - fraction))  # binomial
    assert abs(darkened - n * fraction) < 4 * sd


def test_dark_metals_reach_the_f0_of_the_dataset_metal_that_no_palette_metal_reaches():
    # 2_svbrdf: kd = 0, F0 (RGB mean) 0.05-0.17; undarkened pure metals stay above 0.25.
    def pure_metal_f0(m: ms.SVBRDF) -> torch.Tensor:
        return m.specular.mean(dim=1, keepdim=True)[procedural.pure_metal_texels(m.diffuse)]

    plain, dark = generate(72, size=16, seed=0), generate(72, size=16, seed=0, dark_metals=1.0)
    assert float(pure_metal_f0(plain).min()) > 0.25
    f0 = pure_metal_f0(dark)
    assert bool(((f0 > 0.05) & (f0 < 0.1)).any())


# ---- coverage ------------------------------------------------------------------------------------


def test_coverage_of_roughness_albedos_and_slopes(coverage_set):
    v = stats.texel_values(coverage_set)
    r, ks, kd, slope = v["roughness"], v["ks"], v["kd_luminance"], v["slope_deg"]
    assert r.min() <= 0.03 and r.max() >= 0.95  # glossy to fully rough
    assert ((r > 0.1) & (r < 0.3)).float().mean() > 0.05 and ((r > 0.4) & (r < 0.7)).float().mean() > 0.05
    assert ((ks > 0.02) & (ks < 0.08)).float().mean() > 0.5  # mostly dielectrics ...
    assert (ks > 0.5).float().mean() > 0.05  # ... and metals
    assert (v["ks_chroma"] > 0.2).float().mean() > 0.01  # coloured metals (gold, copper, ...)
    assert (kd < 0.03).float().mean() > 0.05 and (kd > 0.75).float().mean() > 0.02  # near-black and bright
    assert (slope < 2).float().mean() > 0.2 and (slope > 30).float().mean() > 0.002


def test_every_family_spans_its_own_ranges(coverage_set):
    fams = [family_of(i, 0) for i in range(coverage_set.batch_size)]
    summary = stats.material_summary(coverage_set)
    for f in FAMILIES:
        idx = [i for i, g in enumerate(fams) if g == f]
        assert len(idx) == 9, f
        for q in ("roughness", "kd_luminance", "slope_deg"):
            med = summary[q][idx, 1]
            assert med.max() - med.min() > 1e-3, (f, q)  # materials of a family differ
        assert summary["slope_deg"][idx, 2].max() > 1.0, f  # every family has relief
    metal = {f for f in FAMILIES if summary["ks"][[i for i, g in enumerate(fams) if g == f], 1].max() > 0.4}
    assert {"brushed_metal", "hammered_metal"} <= metal


@needs_samples
def test_generated_set_covers_every_percentile_of_the_sample_materials(coverage_set):
    """Each sample material's 1st / 50th / 99th texel percentile of each quantity lies within the
    range of that percentile over the generated set, both at 48 px (the samples area-averaged, as in
    benchmarks/data_statistics.py --size 48). Tolerances: albedos and roughness 1/255 (the samples'
    8-bit storage), slope 1 degree (texels of a 48 px map average 5 x 5 sample texels' normals)."""
    import warnings

    q = torch.tensor([0.01, 0.5, 0.99])

    def percentiles(m: ms.SVBRDF) -> dict[str, torch.Tensor]:
        v = stats.texel_maps(m)
        v.update({f"kd_{c}": m.diffuse[:, i] for i, c in enumerate("rgb")})
        return {k: torch.quantile(t.reshape(t.shape[0], -1).float(), q, dim=1).T for k, t in v.items()}

    gen = percentiles(coverage_set)
    lo = {k: v.min(0).values for k, v in gen.items()}
    hi = {k: v.max(0).values for k, v in gen.items()}
    misses = []
    for f in sorted(SAMPLES.glob("*_svbrdf.png")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the samples' off-unit normals are cleaned, with a warning
            m = ms.SVBRDF.load(f)
        for k, v in percentiles(m.resized(48)).items():
            tol = 1.0 if k == "slope_deg" else 1 / 255
            for j in range(3):
                if not lo[k][j] - tol <= v[0, j] <= hi[k][j] + tol:
                    misses.append(f"{f.stem} {k} p{int(100 * q[j])}={float(v[0, j]):.3g} not in "
                                  f"[{float(lo[k][j]):.3g}, {float(hi[k][j]):.3g}]")
    assert not misses, misses


# ---- the preview command -------------------------------------------------------------------------


def test_materials_preview_writes_a_contact_sheet(tmp_path):
    from PIL import Image

    from mitsvbrdf.cli import main

    out = tmp_path / "sheet.png"
    assert main(["materials", "preview", "--n", "3", "--size", "32", "--tile", "32", "--render-size", "8",
                 "--columns", "1", "--out", str(out), "--quiet"]) == 0
    with Image.open(out) as im:
        w, h = im.size
    assert w >= 5 * 32 and h >= 3 * 32
