"""Resolution transfer: networks trained on one texel grid reconstructing captures on a finer one.

The rig's sample is ``s`` x ``s`` metres whatever the texel grid; networks trained on R x R
materials learned texels of pitch s / R. A U-Net sees a fixed number of texels around each output
texel, so on a 256 x 256 capture of the same sample every structure spans 256 / R times more
texels than in training. The low-frequency cues of the normals (a tilted region shades all five
images alike, only its neighbourhood tells tilt from albedo) then fall outside what the networks
see. The shipped networks (R = 64) bring the sample materials' normal RMSE to half the
flat-normal level at 64 px (0.051 against 0.105), but only a fifth below it on a 256 px capture
(0.090 against 0.114); reconstructed across the grids ("fused"), 0.058
(``benchmarks/resolution_transfer.py``, docs/benchmarks/resolution_transfer.md).

Modes (:data:`TRANSFER_MODES`) for a capture on an H x W grid finer than the networks' R x R
(:func:`working_grid`; an axis at or below R is kept):

* ``"native"``: every network runs on the capture as it is (the behaviour before this module).
* ``"coarse"``: the networks' maps on the working grid (:func:`grid_maps`, below), upsampled
  bilinearly. No detail finer than s / R.
* ``"fused"`` (default): G_sc runs on both grids and the encoded maps keep the coarse run's low
  band and the native run's high band, a two-level Laplacian pyramid::

      M = up(M_R) + (M_H - up(down(M_H)))

  with ``down`` the area average to R x R and ``up`` the bilinear upsampling to H x W. What the
  networks were trained to see comes from the coarse run; from the native run only the detail the
  coarse grid cannot hold. The normal is renormalised when the maps are decoded.
* ``"fused-area"``: "fused" with every map of M_R from the area-averaged capture (the default
  until roughness came from the texel centres, then the phases, below; kept to measure against).
* ``"pyramid"``: "fused" over every octave (:func:`octave_grids`): G_sc runs on the capture
  brought to R, 2R, 4R, ... up to H x W, and each grid adds only the octave the one below it
  cannot hold::

      M_0 = M_R,    M_l = up(M_{l-1}) + (M_{2^l R} - up(down(M_{2^l R}))),

  so every band comes from the grid where its structures are closest to the size the networks
  learned them at (in "fused", the octave between R and 2R comes from the full grid, where it spans
  H / R times more texels than in training). One more G_sc run per octave, on smaller grids than
  the full one.

The maps on a coarser grid (:func:`grid_maps`) come from the capture area-averaged to it (each
coarse texel's mean radiance, :func:`~mitsvbrdf.svbrdf.resample_texels`, what a camera with that
many pixels records), except the roughness. The networks trained on materials constant over each
texel; a coarse texel of a finer material mixes the reflections of differently tilted sub-texels,
which widens a glossy highlight as a rougher surface would (Toksvig's effect): from the area
average the networks read the roughness too high wherever the relief is finer than their grid.
So the roughness is the mean of k^2 more runs on the coarse grid, one per texel phase
(:func:`~mitsvbrdf.svbrdf.texel_phases`, k = H / R): each run sees the capture sampled at one
fine texel of every coarse texel (:func:`~mitsvbrdf.svbrdf.sample_within_texels`), single texels
as in training, and together they see every fine texel once. (A run sees its texels at the
coarse texels' centres, where it computes the irradiance L^d; the offset is under 1% of L^d.)
The other maps stay on the area average, into which the phases would alias fine albedo and relief.
``benchmarks/roughness_bias.py`` (docs/benchmarks/roughness_bias.md; chain 9, 48 procedural
256 px materials outside the test seeds) measures it: on smooth materials (mean roughness < 0.3)
the roughness bias is +0.057 from the area average, +0.024 from the capture sampled at the
texel centres (one run, the default before the phases), -0.006 from the phases and +0.001 for
the same materials reconstructed at 64 px. Over all 48 the roughness RMSE is 0.074 from the
phases, 0.080 from the centres and 0.091 from the area average (the phases lower than the centres
by 0.0061 +- 0.0027 per material, on 29 of the 48). Rejected there: the phases' low band without
the capture's own detail (0.077), and narrowing alpha^2 by the slope variance of the
reconstructed normals within each coarse texel (Toksvig's widening inverted; roughness RMSE
0.129): the networks do not read roughness as that model does, and it overshoots on smooth and
rough materials alike.

In every mode but "native" the initializer and G_l predict from the area-averaged I_0 (the
patterns live on the LCD's grid, the same for any texel grid), and the initializer's estimate is upsampled to H x W.

Rejected: reconstructing tile by tile at the native pitch (the tiles are the training size in
texels but a sixteenth of the sample: the same loss of context, with seams).
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

from .errors import MitsvbrdfError
from .svbrdf import ENCODED_SLICES, resample_texels, sample_within_texels, texel_phases

#: How networks trained on one texel grid meet a finer capture (module docstring).
TRANSFER_MODES = ("native", "coarse", "fused", "fused-area", "pyramid")

#: The mode acquisitions use unless told otherwise.
DEFAULT_TRANSFER = "fused"

#: The command-line help of every ``--transfer`` option.
TRANSFER_HELP = ("how a capture finer than the networks' training grid is reconstructed: fused (default: the "
                 "training grid's maps, the capture's own detail on top), pyramid (the same over every octave), "
                 "coarse (the training grid's maps, upsampled), native (the networks on the capture as it is) or "
                 "fused-area (fused with the roughness from the area-averaged capture too)")


def check_transfer(mode: str) -> str:
    """``mode`` if it is one of :data:`TRANSFER_MODES`, else MitsvbrdfError."""
    if mode not in TRANSFER_MODES:
        raise MitsvbrdfError(f"transfer must be one of {', '.join(TRANSFER_MODES)}, got {mode!r}")
    return mode


def working_grid(shape: tuple[int, int], trained: int | None) -> tuple[int, int]:
    """The texel grid (h, w) the networks run on for an H x W capture: each axis capped at the
    ``trained`` resolution R (None, unknown: the capture's own grid)."""
    h, w = int(shape[0]), int(shape[1])
    if trained is None:
        return h, w
    return min(h, trained), min(w, trained)


def octave_grids(shape: tuple[int, int], trained: int | None) -> list[tuple[int, int]]:
    """The texel grids of mode "pyramid" for an H x W capture, coarsest first: the working grid,
    then each axis doubled (capped at the capture's) until the capture's own grid."""
    full = (int(shape[0]), int(shape[1]))
    grids = [working_grid(full, trained)]
    while grids[-1] != full:
        grids.append(tuple(min(2 * g, f) for g, f in zip(grids[-1], full)))
    return grids


def fuse_bands(coarse: Tensor, fine: Tensor) -> Tensor:
    """Low band of ``coarse`` (B, C, h, w), high band of ``fine`` (B, C, H, W) -> (B, C, H, W):
    up(coarse) + fine - up(down(fine)) (module docstring)."""
    size = tuple(fine.shape[-2:])
    return resample_texels(coarse, size) + fine - resample_texels(resample_texels(fine, tuple(coarse.shape[-2:])), size)


def grid_maps(run: Callable[[Tensor], Tensor], images: Tensor, grid: tuple[int, int],
              phased_roughness: bool = True) -> Tensor:
    """The (B, 10, h, w) encoded maps of ``run`` for a capture ``images`` (B, P, 3, H, W) brought to
    the coarser ``grid`` (h, w): from the area-averaged capture, with the roughness, where
    ``phased_roughness``, the mean of the runs on the capture sampled at each of
    :func:`~mitsvbrdf.svbrdf.texel_phases` (one run per fine texel a coarse texel covers, each
    seeing one fine texel of every coarse texel; module docstring)."""
    maps = run(resample_texels(images, grid))
    phases = texel_phases(tuple(images.shape[-2:]), grid)
    if not phased_roughness or len(phases) == 1:
        return maps
    r = ENCODED_SLICES["roughness"]
    rough = sum(run(sample_within_texels(images, grid, at))[:, r] for at in phases) / len(phases)
    return torch.cat([maps[:, :r.start], rough, maps[:, r.stop:]], dim=1)


def reconstruct_across(run: Callable[[Tensor], Tensor], images: Tensor, trained: int | None,
                       mode: str = DEFAULT_TRANSFER) -> Tensor:
    """``run(images (B, P, 3, h, w)) -> (B, 10, h, w)`` encoded maps, applied to a capture
    ``images`` (B, P, 3, H, W) in ``mode`` for networks trained at ``trained`` texels a side.
    Returns (B, 10, H, W). On the networks' own grid (or in "native") it is ``run(images)``."""
    check_transfer(mode)
    full = tuple(images.shape[-2:])
    grid = working_grid(full, trained)
    if mode == "native" or grid == full:
        return run(images)
    phased = mode != "fused-area"
    maps = grid_maps(run, images, grid, phased)
    if mode == "coarse":
        return resample_texels(maps, full)
    finer = octave_grids(full, trained)[1:] if mode == "pyramid" else [full]  # "fused": one step to the capture
    for g in finer:
        maps = fuse_bands(maps, run(images) if g == full else grid_maps(run, images, g, phased))
    return maps


def prediction_input(image: Tensor, trained: int | None, mode: str = DEFAULT_TRANSFER) -> Tensor:
    """What the initializer and G_l predict from: ``image`` (B, 3, H, W) area-averaged to the
    working grid in "coarse", "fused" and "pyramid", as it is in "native"."""
    check_transfer(mode)
    return image if mode == "native" else resample_texels(image, working_grid(tuple(image.shape[-2:]), trained))
