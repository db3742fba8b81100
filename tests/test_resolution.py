"""Resolution transfer: networks trained on an R x R grid reconstructing a finer capture."""

import pytest
import torch

from mitsvbrdf.errors import MitsvbrdfError
from mitsvbrdf.resolution import (TRANSFER_MODES, check_transfer, octave_grids, prediction_input, reconstruct_across,
                                  working_grid)
from mitsvbrdf.svbrdf import ENCODED_SLICES, resample_texels, sample_within_texels, texel_phases

# float32 sums of a few texels: a few units in the last place of values near 1
EPS = 1e-6
ROUGH = ENCODED_SLICES["roughness"]
NOT_ROUGH = [c for c in range(10) if c != ROUGH.start]


def per_texel(images):
    """A stand-in G_sc that is one linear map per texel (the mean over the patterns, as ten
    encoded channels): it gives the same maps whatever the grid, so every mode must reproduce what
    it gives on the capture, except where a mode samples the capture differently (roughness)."""
    m = images.mean(1)
    return torch.cat([m, m, m[:, :1], m], dim=1)


def squared_per_texel(images):
    """A grid-independent stand-in G_sc that is nonlinear per texel (the square of per_texel): the
    mean of its maps over a block's texels differs from its map of the block's mean radiance."""
    return per_texel(images) ** 2


def block_mean(t, block=4):
    """(B, C, H, W) -> (B, C, H / block, W / block): the mean over each block x block texels."""
    b, c, h, w = t.shape
    return t.reshape(b, c, h // block, block, w // block, block).mean(dim=(3, 5))


def test_the_working_grid_caps_each_axis_at_the_training_resolution():
    assert working_grid((256, 256), 64) == (64, 64)
    assert working_grid((256, 32), 64) == (64, 32)
    assert working_grid((32, 32), 64) == (32, 32)


def test_an_unknown_training_resolution_keeps_the_capture_grid():
    assert working_grid((256, 128), None) == (256, 128)


def test_bad_modes_are_refused():
    with pytest.raises(MitsvbrdfError, match="transfer must be one of native, coarse, fused, fused-area, pyramid"):
        check_transfer("tiled")
    with pytest.raises(MitsvbrdfError):
        reconstruct_across(per_texel, torch.rand(1, 5, 3, 8, 8), 4, "tiled")


@pytest.mark.parametrize("mode", TRANSFER_MODES)
def test_a_capture_on_the_training_grid_is_reconstructed_as_it_is(mode):
    images = torch.rand(2, 5, 3, 16, 16)
    calls = []
    out = reconstruct_across(lambda x: calls.append(x.shape) or per_texel(x), images, 16, mode)
    assert calls == [images.shape]
    assert torch.equal(out, per_texel(images))


def test_native_mode_runs_the_networks_on_the_finer_capture_only():
    images = torch.rand(1, 5, 3, 32, 32)
    calls = []
    reconstruct_across(lambda x: calls.append(tuple(x.shape[-2:])) or per_texel(x), images, 8, "native")
    assert calls == [(32, 32)]


def test_sampling_within_texels_4x_coarser_at_the_centre_averages_each_blocks_central_2x2():
    t = torch.rand(2, 3, 16, 16)
    want = t.reshape(2, 3, 4, 4, 4, 4)[:, :, :, 1:3, :, 1:3].mean(dim=(3, 5))
    assert torch.allclose(sample_within_texels(t, (4, 4)), want, atol=EPS)


def test_sampling_within_texels_2x_coarser_at_the_centre_is_the_area_average():
    t = torch.rand(1, 5, 3, 16, 16)
    assert torch.allclose(sample_within_texels(t, (8, 8)), resample_texels(t, (8, 8)), atol=EPS)


def test_each_texel_phase_samples_one_texel_of_every_block():
    t = torch.rand(1, 5, 3, 16, 12)
    phases = texel_phases((16, 12), (4, 3))
    assert len(phases) == 16
    for at in phases:
        i, j = int(at[0] * 4), int(at[1] * 4)
        assert torch.allclose(sample_within_texels(t, (4, 3), at), t[..., i::4, j::4], atol=EPS)


def test_texel_phases_round_a_fractional_ratio_up():
    assert texel_phases((10, 8), (4, 8)) == [(1 / 6, 0.5), (0.5, 0.5), (5 / 6, 0.5)]


def test_sampling_within_texels_refuses_a_finer_grid():
    with pytest.raises(ValueError, match="coarser grid"):
        sample_within_texels(torch.rand(1, 3, 8, 8), (16, 16))


def test_coarse_mode_runs_the_networks_on_the_area_average_and_on_every_texel_phase():
    images = torch.rand(1, 5, 3, 32, 32)
    calls = []
    out = reconstruct_across(lambda x: calls.append(tuple(x.shape[-2:])) or per_texel(x), images, 8, "coarse")
    assert calls == [(8, 8)] * (1 + 16) and out.shape == (1, 10, 32, 32)


def test_coarse_mode_upsamples_the_maps_of_the_area_averaged_capture_but_roughness():
    images = torch.rand(1, 5, 3, 32, 32)
    out = reconstruct_across(squared_per_texel, images, 8, "coarse")
    want = resample_texels(squared_per_texel(resample_texels(images, (8, 8))), (32, 32))
    assert torch.allclose(out[:, NOT_ROUGH], want[:, NOT_ROUGH], atol=EPS)


def test_coarse_mode_takes_the_roughness_from_the_mean_over_the_texel_phases():
    # each phase's run sees single texels: their mean is the block mean of the per-texel maps,
    # not the map of the block's mean radiance
    images = torch.rand(1, 5, 3, 32, 32)
    out = reconstruct_across(squared_per_texel, images, 8, "coarse")
    want = resample_texels(block_mean(squared_per_texel(images)), (32, 32))
    assert torch.allclose(out[:, ROUGH], want[:, ROUGH], atol=EPS)


def test_fused_mode_gives_a_grid_independent_network_its_own_maps_but_roughness():
    images = torch.rand(1, 5, 3, 32, 32)
    out = reconstruct_across(per_texel, images, 8, "fused")
    assert torch.allclose(out[:, NOT_ROUGH], per_texel(images)[:, NOT_ROUGH], atol=EPS)


def test_fused_mode_gives_a_nonlinear_per_texel_network_its_own_roughness():
    # the phases' low band is the block mean of the per-texel maps, which the capture's own detail
    # completes to the per-texel maps; from the area average ("fused-area") it does not
    images = torch.rand(1, 5, 3, 32, 32)
    own = squared_per_texel(images)[:, ROUGH]
    assert torch.allclose(reconstruct_across(squared_per_texel, images, 8, "fused")[:, ROUGH], own, atol=EPS)
    assert not torch.allclose(reconstruct_across(squared_per_texel, images, 8, "fused-area")[:, ROUGH], own,
                              atol=1e-3)


def test_fused_area_mode_gives_a_grid_independent_linear_network_all_its_own_maps():
    images = torch.rand(1, 5, 3, 32, 32)
    calls = []
    out = reconstruct_across(lambda x: calls.append(tuple(x.shape[-2:])) or per_texel(x), images, 8, "fused-area")
    assert calls == [(8, 8), (32, 32)]
    assert torch.allclose(out, per_texel(images), atol=EPS)


def test_fused_mode_takes_the_low_band_from_the_training_grid():
    # a network whose maps on the training grid are offset by 0.25 everywhere (a low-band
    # difference): the fused maps carry the offset, and the capture's own detail beside it
    images = torch.rand(1, 5, 3, 32, 32)
    run = lambda x: per_texel(x) + (0.25 if x.shape[-1] == 8 else 0.0)  # noqa: E731
    out = reconstruct_across(run, images, 8, "fused")
    assert torch.allclose(out[:, NOT_ROUGH], per_texel(images)[:, NOT_ROUGH] + 0.25, atol=EPS)


def test_the_octave_grids_double_from_the_working_grid_to_the_capture():
    assert octave_grids((256, 256), 64) == [(64, 64), (128, 128), (256, 256)]
    assert octave_grids((192, 64), 32) == [(32, 32), (64, 64), (128, 64), (192, 64)]
    assert octave_grids((32, 32), 64) == [(32, 32)]


def test_pyramid_mode_runs_the_networks_on_every_octave_and_on_each_coarser_grids_phases():
    # 8 px: the area average and 16 phases of 4 x 4; 16 px: the area average and 4 phases of 2 x 2
    images = torch.rand(1, 5, 3, 32, 32)
    calls = []
    reconstruct_across(lambda x: calls.append(tuple(x.shape[-2:])) or per_texel(x), images, 8, "pyramid")
    assert calls == [(8, 8)] * (1 + 16) + [(16, 16)] * (1 + 4) + [(32, 32)]


def test_pyramid_mode_gives_a_grid_independent_network_its_own_maps_but_roughness():
    images = torch.rand(1, 5, 3, 32, 32)
    out = reconstruct_across(per_texel, images, 8, "pyramid")
    assert torch.allclose(out[:, NOT_ROUGH], per_texel(images)[:, NOT_ROUGH], atol=EPS)


def test_pyramid_mode_takes_each_octave_from_its_own_grid():
    # a network that adds a per-grid offset: only the training grid's reaches the low band, and the
    # finer grids' offsets (constant, no detail above their octave) vanish from the result
    images = torch.rand(1, 5, 3, 32, 32)
    offset = {8: 0.25, 16: -0.5, 32: 1.0}
    out = reconstruct_across(lambda x: per_texel(x) + offset[x.shape[-1]], images, 8, "pyramid")
    assert torch.allclose(out[:, NOT_ROUGH], per_texel(images)[:, NOT_ROUGH] + 0.25, atol=EPS)


def test_pyramid_mode_takes_the_middle_octave_from_the_middle_grid():
    # detail only the 16 px run sees (a checkerboard at its texel pitch, which the 8 px grid
    # averages away) is its octave: it reaches the result whole, upsampled to the capture's grid
    images = torch.zeros(1, 5, 3, 32, 32)
    checker = (torch.arange(16)[:, None] + torch.arange(16)[None]) % 2 - 0.5
    run = lambda x: per_texel(x) + (checker if x.shape[-1] == 16 else 0.0)  # noqa: E731
    out = reconstruct_across(run, images, 8, "pyramid")
    want = resample_texels(checker.expand(1, 10, 16, 16), (32, 32))
    assert torch.allclose(out, want, atol=EPS)


def test_patterns_are_predicted_from_the_area_averaged_first_image():
    i0 = torch.rand(2, 3, 32, 32)
    assert prediction_input(i0, 8, "native") is i0
    for mode in ("coarse", "fused", "fused-area", "pyramid"):
        assert torch.allclose(prediction_input(i0, 8, mode), resample_texels(i0, (8, 8)))
