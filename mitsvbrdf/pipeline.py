"""The adaptive acquisition pipeline (paper Fig. 2), for one material or a batch.

    I_0 under L_0 -> initializer -> (normal, roughness) -> L_pdf -> G_l -> 4 adaptive patterns
    -> capture I_1..I_4 (simulated through a renderer, or a real device) -> I^spec (separation)
    -> G_sc -> SVBRDF maps

The learned parts are injected as modules, so the same pipeline serves trained weights, the
baselines and tests:

* ``l0``: (3, h, w) drive values of the first pattern;
* ``initializer(i0 (B, 3, H, W)) -> (B, 10, H, W)`` encoded maps (normal and roughness are used);
* ``lighting(i0, lpdf (B, 1, h, w))`` -> an object with ``patterns`` (B, 4, 3, h, w) in [0, 1];
* ``reconstructor(images (B, 5, 3, H, W), spec (B, 10, 3, H, W)) -> (B, 10, H, W)`` encoded maps
  (``spec`` is None for a reconstructor whose ``use_spec`` attribute is False).

Images are linear radiance on the sample's texel grid. Single-material calls take and return
tensors without the batch dimension.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .checks import SEED_MAX, check_int
from .errors import MitsvbrdfError
from .importance import importance
from .patterns import prepend_pattern
from .render import render
from .rig import Rig
from .separation import reconstruct_maps
from .svbrdf import SVBRDF


#: simulate() seeds capture step k (1..99) with seed * 100 + k, a UInt32.
SIMULATE_SEED_MAX = (SEED_MAX - 99) // 100


@dataclass
class Acquisition:
    """Everything one acquisition produced (tensors without batch dimension for one material)."""

    patterns: Tensor        # (5, 3, h, w) drive values, L_0 first
    images: Tensor          # (5, 3, H, W) linear radiance
    lpdf: Tensor            # (1, h, w) the importance distribution the patterns were predicted from
    initial: SVBRDF         # the initializer's estimate (normal and roughness drive L_pdf)
    svbrdf: SVBRDF          # the reconstruction


class AcquisitionPipeline(torch.nn.Module):
    """Pattern prediction and reconstruction around injected networks (module docstring).

    Args:
        l0, initializer, lighting, reconstructor: see the module docstring.
        rig: the capture rig (L_pdf and the separation need its geometry and display model).
        lpdf_stride: texel stride of the L_pdf quadrature (4: 0.9 s for 256 x 256 on 2 cores).
        lpdf_from: "initializer" (the method), or "uniform" (the paper's fixed-L_pdf ablation).
    """

    def __init__(self, l0: Tensor, initializer: torch.nn.Module, lighting: torch.nn.Module,
                 reconstructor: torch.nn.Module, rig: Rig, *, lpdf_stride: int = 4,
                 lpdf_from: str = "initializer"):
        super().__init__()
        if lpdf_from not in ("initializer", "uniform"):
            raise ValueError(f"lpdf_from must be 'initializer' or 'uniform', got {lpdf_from!r}")
        h, w = rig.lcd_cells
        if tuple(l0.shape) != (3, h, w):
            raise ValueError(f"l0 must be (3, {h}, {w}) for this rig, got {tuple(l0.shape)}")
        self.register_buffer("l0", l0.detach().clone())
        self.initializer, self.lighting, self.reconstructor = initializer, lighting, reconstructor
        self.rig, self.lpdf_stride, self.lpdf_from = rig, lpdf_stride, lpdf_from

    @property
    def size_multiple(self) -> int:
        """Materials must be H x W with H and W multiples of this (the U-Nets' downsampling)."""
        return size_multiple(self)

    def check_resolution(self, resolution: int | tuple[int, int], what: str = "the material") -> None:
        """Raise MitsvbrdfError unless these networks can take an H x W capture; call it before
        rendering anything."""
        check_resolution(resolution, self.size_multiple, what)

    @torch.no_grad()
    def predict_patterns(self, i0: Tensor) -> tuple[Tensor, Tensor, SVBRDF]:
        """I_0 (B, 3, H, W) -> (adaptive patterns (B, 4, 3, h, w), L_pdf (B, 1, h, w), initial SVBRDF)."""
        initial = maps_to_svbrdf(self.initializer(i0))
        if self.lpdf_from == "uniform":
            lpdf = torch.ones(i0.shape[0], 1, *self.rig.lcd_cells, device=i0.device, dtype=i0.dtype)
        else:
            lpdf = importance(initial.normal, initial.roughness, self.rig, texel_stride=self.lpdf_stride)
        return self.lighting(i0, lpdf).patterns.clamp(0, 1), lpdf, initial

    @torch.no_grad()
    def reconstruct(self, images: Tensor, patterns: Tensor) -> SVBRDF:
        """Images (B, 5, 3, H, W) under patterns (B, 5, 3, h, w) -> the reconstructed SVBRDF."""
        return maps_to_svbrdf(reconstruct_maps(self.reconstructor, images, patterns, self.rig))

    def all_patterns(self, adaptive: Tensor) -> Tensor:
        """L_0 prepended to adaptive patterns (B, 4, 3, h, w) -> (B, 5, 3, h, w)."""
        return prepend_pattern(self.l0, adaptive)

    @torch.no_grad()
    def acquire(self, capture, batch: int = 1) -> Acquisition | list[Acquisition]:
        """Run the acquisition with ``capture(patterns (B, P, 3, h, w)) -> images (B, P, 3, H, W)``
        (a renderer or a device): show L_0, predict, show the 4 adaptive patterns, reconstruct."""
        l0 = self.l0[None, None].expand(batch, 1, *self.l0.shape)
        i0 = capture(l0)[:, 0]
        adaptive, lpdf, initial = self.predict_patterns(i0)
        rest = capture(adaptive)
        patterns = self.all_patterns(adaptive)
        images = torch.cat([i0[:, None], rest], 1)
        svbrdf = self.reconstruct(images, patterns)
        out = [Acquisition(patterns[b], images[b], lpdf[b], initial[b], svbrdf[b]) for b in range(batch)]
        return out[0] if batch == 1 else out

    def simulate(self, svbrdf: SVBRDF, method: str = "mitsuba", spp: int = 64, seed: int = 0,
                 noise=None) -> Acquisition | list[Acquisition]:
        """Acquire ``svbrdf`` (B materials) through a renderer (and an optional noise model
        ``noise(images, generator)``), with a fixed seed per capture step."""
        check_int("seed", seed, 0, SIMULATE_SEED_MAX)
        self.check_resolution(svbrdf.resolution)
        g = torch.Generator(device=svbrdf.device).manual_seed(seed)
        step = iter(range(1, 100))

        def capture(patterns: Tensor) -> Tensor:
            with torch.no_grad():
                imgs = render(svbrdf, patterns, self.rig, method=method, spp=spp, seed=seed * 100 + next(step))
            return imgs if noise is None else noise(imgs, g)

        return self.acquire(capture, batch=svbrdf.batch_size)


def size_multiple(*modules: torch.nn.Module) -> int:
    """The least common multiple of the input-size factors of every U-Net encoder in ``modules``
    (1 when there is none): H and W of their inputs must be multiples of it."""
    from .nets.nafnet import NAFEncoder

    f = 1
    for m in modules:
        for sub in m.modules():
            if isinstance(sub, NAFEncoder):
                f = math.lcm(f, sub.factor)
    return f


def check_resolution(resolution: int | tuple[int, int], multiple: int, what: str = "the material") -> None:
    """Raise MitsvbrdfError unless H and W are positive multiples of ``multiple``."""
    h, w = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
    if h < 1 or w < 1 or h % multiple or w % multiple:
        raise MitsvbrdfError(f"{what} is {h}x{w} texels; these networks need a size that is a positive "
                             f"multiple of {multiple} (e.g. {max(multiple, (max(h, 1) // multiple) * multiple)})")


def maps_to_svbrdf(encoded: Tensor) -> SVBRDF:
    """Network output (B, 10, H, W) -> a valid SVBRDF: values clipped to [0, 1] and the encoded
    normal's z kept above 1/2, so that every decoded normal faces up."""
    t = encoded.clamp(0.0, 1.0)
    t = torch.cat([t[:, :2], t[:, 2:3].clamp_min(0.5 + 1e-3), t[:, 3:]], 1)
    return SVBRDF.from_encoded(t)
