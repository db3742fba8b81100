"""Pattern families: shapes, ranges, layout, files, and clear errors for bad patterns."""

import numpy as np
import pytest
import torch

from mitsvbrdf import patterns as pt
from mitsvbrdf.errors import PatternError


@pytest.mark.parametrize("name,count", [("uniform", 1), ("monograd", 5), ("colorgrad", 5), ("step_edges", 10), ("random", 5)])
def test_families_give_drive_values_in_unit_range(name, count):
    p = pt.pattern_family(name, 32, 32)
    assert p.shape == (count, 3, 32, 32) and p.dtype == torch.float32
    assert p.min() >= 0 and p.max() <= 1


def test_monograd_is_constant_x_y_and_complements():
    p = pt.monograd(4, 8)
    assert (p[:, 0] == p[:, 1]).all() and (p[:, 1] == p[:, 2]).all()
    assert (p[0] == 1).all()
    assert (p[1, 0, 0, 1:] > p[1, 0, 0, :-1]).all() and (p[1, 0, 1:, 0] == p[1, 0, :-1, 0]).all()
    assert (p[2, 0, 1:, 0] > p[2, 0, :-1, 0]).all()
    torch.testing.assert_close(p[3], 1 - p[1])
    torch.testing.assert_close(p[4], 1 - p[2])


def test_colorgrad_complements_sum_to_white():
    p = pt.colorgrad(16, 16)
    torch.testing.assert_close(p[1] + p[2], torch.ones(3, 16, 16))
    torch.testing.assert_close(p[3] + p[4], torch.ones(3, 16, 16))
    z = p[1, 2]
    assert z[8, 8] > z[0, 0] and z[8, 8] > z[15, 15]


def test_step_edges_switch_along_both_axes():
    p = pt.step_edges(8, 8, n=4)
    assert set(p.unique().tolist()) == {0.0, 1.0}
    assert (p[0, :, :, 0] == 0).all() and (p[0, :, :, -1] == 1).all()
    assert (p[2, :, 0, :] == 0).all() and (p[2, :, -1, :] == 1).all()


def test_random_patterns_are_seeded():
    torch.testing.assert_close(pt.random(seed=3), pt.random(seed=3))
    assert not torch.equal(pt.random(seed=3), pt.random(seed=4))


def test_patterns_load_from_npy_and_png_strip(tmp_path):
    from mitsvbrdf import imageio
    p = pt.random(8, 8, n=3, seed=0)
    np.save(tmp_path / "p.npy", p.numpy())
    torch.testing.assert_close(pt.load_patterns(tmp_path / "p.npy", 8, 8), p)
    strip = p.permute(2, 0, 3, 1).reshape(8, 24, 3).numpy()
    imageio.write_png(tmp_path / "p.png", strip, bits=16)
    torch.testing.assert_close(pt.load_patterns(tmp_path / "p.png", 8, 8), p, atol=1e-4, rtol=0)


def test_one_pattern_is_named_by_its_group_and_index():
    assert torch.equal(pt.load_pattern("colorgrad[1]"), pt.pattern_family("colorgrad")[1])
    assert torch.equal(pt.load_pattern("monograd"), pt.pattern_family("monograd")[0])


@pytest.mark.parametrize("spec, match", [("colorgrad[5]", "holds 5 patterns"), ("colorgrad[x]", "whole number"),
                                         ("colorgrad[-1]", "whole number"), ("nothing[0]", "neither a pattern family")])
def test_a_bad_pattern_name_or_index_is_a_clear_error(spec, match):
    with pytest.raises(PatternError, match=match):
        pt.load_pattern(spec)


def test_unknown_family_and_wrong_file_shape_are_clear_errors(tmp_path):
    with pytest.raises(PatternError, match="neither a pattern family"):
        pt.load_patterns("sunset")
    np.save(tmp_path / "bad.npy", np.zeros((2, 3, 8, 9), np.float32))
    with pytest.raises(PatternError, match=r"\(P, 3, 8, 8\)"):
        pt.load_patterns(tmp_path / "bad.npy", 8, 8)


@pytest.mark.parametrize("bad,match", [
    (torch.full((1, 3, 32, 32), 1.5), r"\[0, 1\]"),
    (torch.full((1, 3, 32, 32), -0.1), r"\[0, 1\]"),
    (torch.full((1, 3, 32, 32), float("nan")), "NaN"),
    (torch.ones(1, 3, 16, 16), "32x32-cell"),
    (torch.ones(3, 32, 32), "32x32-cell"),
])
def test_rig_rejects_bad_patterns(rig, bad, match):
    with pytest.raises(PatternError, match=match):
        rig.check_patterns(bad)


def test_picked_group_has_five_valid_patterns_with_colour_variation():
    p = pt.pattern_family("picked")
    assert p.shape == (5, 3, 32, 32)
    assert p.min() >= 0 and p.max() <= 1
    chroma = (p.max(1).values - p.min(1).values).mean((1, 2))
    assert (chroma[2:] > 0.3).all() and (chroma[:2] == 0).all()


def test_pca_patterns_recover_the_mean_and_the_dominant_direction():
    g = torch.Generator().manual_seed(0)
    u, _ = torch.meshgrid(torch.linspace(0, 1, 8), torch.linspace(0, 1, 8), indexing="ij")
    base = torch.exp(-((u - 0.5) ** 2) * 10)
    coef = torch.randn(64, generator=g)
    lpdf = base + coef.view(-1, 1, 1) * u + 0.01 * torch.randn(64, 8, 8, generator=g)
    p = pt.pca_patterns(lpdf, n=3)
    assert p.shape == (3, 3, 8, 8) and p.min() >= 0 and p.max() <= 1
    first = p[1, 0]
    corr = torch.corrcoef(torch.stack([first.flatten(), u.flatten()]))[0, 1]
    assert corr > 0.99  # the leading component is the varying ramp


def test_pca_patterns_need_enough_maps():
    with pytest.raises(PatternError, match="at least 5"):
        pt.pca_patterns(torch.rand(3, 1, 8, 8))
