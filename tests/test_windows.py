"""A window of the sample (``Rig.window``) renders as the crop of the whole material, with every
renderer: training on crops of a large material needs each texel to keep its place in the rig,
and so its light and view directions."""

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import patterns as pt
from mitsvbrdf.data.augment import crop_maps

from conftest import jit_kernels_of, textured_material

SIZE, TOP, LEFT, CROP = 16, 2, 8, 8
PATTERNS = torch.cat([pt.monograd()[1:3], pt.random(n=1, seed=4)])


def _crop(t):
    return t[..., TOP:TOP + CROP, LEFT:LEFT + CROP]


@pytest.fixture(scope="module")
def whole():
    return textured_material(SIZE, seed=5, roughness=(0.05, 0.5))


@pytest.fixture(scope="module")
def window(whole):
    return ms.SVBRDF(**crop_maps(whole.maps(), TOP, LEFT, CROP))


# Per-texel quadrature in float32: the same sums in another order at most, so a few float32 ulps
# over the ~10^3 terms of a texel.
TOL = dict(rtol=1e-5, atol=1e-7)


def test_the_reference_renders_a_window_as_the_crop_of_the_whole(rig, whole, window):
    got = ms.render(window, PATTERNS, rig.window(SIZE, TOP, LEFT, CROP))
    torch.testing.assert_close(got, _crop(ms.render(whole, PATTERNS, rig)), **TOL)


@pytest.mark.parametrize("mode", ["exact", "prefiltered"])
def test_ltc_renders_a_window_as_the_crop_of_the_whole(rig, whole, window, mode):
    got = ms.render(window, PATTERNS, rig.window(SIZE, TOP, LEFT, CROP), method="ltc", mode=mode)
    torch.testing.assert_close(got, _crop(ms.render(whole, PATTERNS, rig, method="ltc", mode=mode)), **TOL)


def test_mitsuba_renders_a_window_where_the_rig_has_it(rig, window):
    # The plugins' texels come from the loaded scene's sample rectangle: unless it is moved to the
    # window, they are the centre of the sample, lit from elsewhere (several times this tolerance,
    # the repository's 1024-spp agreement criterion).
    win = rig.window(SIZE, TOP, LEFT, CROP)
    got = ms.render(window, PATTERNS, win, method="mitsuba", spp=1024, seed=1)
    want = ms.render(window, PATTERNS, win)
    assert ((got - want).square().mean().sqrt() / want.square().mean().sqrt()).item() < 0.02


def test_mitsuba_puts_the_sample_back_after_a_window(rig, whole, window):
    before = ms.render(whole, PATTERNS, rig, method="mitsuba", spp=4, seed=3)
    ms.render(window, PATTERNS, rig.window(SIZE, TOP, LEFT, CROP), method="mitsuba", spp=4, seed=3)
    torch.testing.assert_close(ms.render(whole, PATTERNS, rig, method="mitsuba", spp=4, seed=3), before, rtol=0, atol=0)


def test_mitsuba_renders_a_new_window_with_the_compiled_kernels(rig, whole):
    # Training draws a new window every step: a window must not compile new kernels (it did while
    # the sample's transform went into the kernels as literals). Dr.Jit's on-disk kernel cache can
    # make even such a kernel a cache hit on a second run of the tests, so the kernels are also
    # compared by hash: another window must launch the very kernels the one before it did.
    def render_at(top, left):
        maps = ms.SVBRDF(**crop_maps(whole.maps(), top, left, CROP))
        ms.render(maps, PATTERNS, rig.window(SIZE, top, left, CROP), method="mitsuba", spp=4, seed=3)

    render_at(0, 0)
    hist = jit_kernels_of(lambda: render_at(TOP, LEFT))
    assert hist and all(k["cache_hit"] for k in hist)
    again = jit_kernels_of(lambda: render_at(TOP - 1, LEFT - 5))
    assert {k["hash"] for k in again} == {k["hash"] for k in hist}


# ---- per-texel geometry caches: a window's is its rows of the whole grid's ------------------------


def _unwindowed(rig):
    """The same rig, not known to be a window: its caches compute everything afresh."""
    import dataclasses

    return dataclasses.replace(rig, window_of=None)


def test_the_flat_diffuse_kernel_of_a_window_is_its_rows_of_the_whole_grids(rig):
    from mitsvbrdf.separation import flat_diffuse_kernel

    win = rig.window(SIZE, TOP, LEFT, CROP)
    torch.testing.assert_close(flat_diffuse_kernel(win, (CROP, CROP)), flat_diffuse_kernel(_unwindowed(win), (CROP, CROP)),
                               **TOL)


def test_the_control_variate_of_a_window_is_the_one_computed_afresh(rig, window):
    from mitsvbrdf.render.control_variate import control_variate

    win = rig.window(SIZE, TOP, LEFT, CROP)
    got = control_variate(window, PATTERNS.unsqueeze(0), win)
    want = control_variate(window, PATTERNS.unsqueeze(0), _unwindowed(win))
    torch.testing.assert_close(got.known, want.known, **TOL)
    torch.testing.assert_close(got.texel, want.texel, **TOL)
    torch.testing.assert_close(got.lobe_grid, want.lobe_grid, **TOL)
