"""The acquisition method (paper Fig. 2): one owner for how a material is acquired and reconstructed.

    L_0 -> capture I_0 -> initializer -> (normal, roughness) -> L_pdf -> G_l -> 4 adaptive patterns
    -> capture I_1..I_4 -> I^spec (separation) -> G_sc -> SVBRDF maps

The steps are functions that inference and training share: :func:`predict` (I_0 -> L_pdf -> the
adaptive patterns) and :func:`reconstruct_maps` (captures -> G_sc's encoded maps; G_sc alone on any grid:
:func:`map_predictor`). Around them:

* :class:`AdaptiveAcquisition` runs the steps with trained (or injected) networks, for a capture
  function of any kind (a renderer in :meth:`~AdaptiveAcquisition.simulate`, the bench's devices
  in :class:`mitsvbrdf.capture.session.CaptureSession`);
* :class:`FixedAcquisition` and :class:`FlashAcquisition` are the baselines (one pattern group for
  every material; one image under a flash);
* :func:`load_adaptive`, :func:`load_baseline` read a ``networks.pt`` export together with the
  :class:`AcquisitionSettings` it was trained with;
* :class:`Acquisition` is the record of one acquisition.

The learned parts are injected as modules, so the same code serves trained weights and tests:

* ``l0``: (3, h, w) drive values of the first pattern;
* ``initializer(i0 (B, 3, H, W)) -> (B, 10, H, W)`` encoded maps (normal and roughness are used);
  one whose ``diffuse_ratio`` attribute is true is also given ``irradiance=`` L_0's L^d (1, 3, H, W);
* ``lighting(i0, lpdf (B, 1, h, w))`` -> an object with ``patterns`` (B, 4, 3, h, w) in [0, 1];
* ``reconstructor(images (B, P, 3, H, W), spec (B, P(P-1)/2, 3, H, W) | None) -> (B, 10, H, W)``
  encoded maps (``spec`` is None when the settings' ``use_spec`` is False); a reconstructor whose
  ``diffuse_ratio`` attribute is true is also given ``irradiance=`` the patterns' L^d (B, P, 3, H, W).

Images are linear radiance on the sample's texel grid. Single-material calls take and return
tensors without the batch dimension. A capture finer than the networks' training grid is
reconstructed across the two grids, in the ``transfer`` mode of :mod:`mitsvbrdf.resolution`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from .checks import SEED_MAX, check_int
from .errors import MitsvbrdfError
from .importance import importance
from .nets import NAFEncoder, NetworkFileError, network_from_record
from .nets.io import read_network_file
from .patterns import prepend_pattern
from .render import render
from .render.quadrature import QuadratureSettings
from .resolution import DEFAULT_TRANSFER, check_transfer, prediction_input, reconstruct_across
from .rig import Rig
from .separation import diffuse_irradiance, separate_specular
from .svbrdf import SVBRDF

#: simulate() seeds capture step k (1..99) with seed * 100 + k, a UInt32.
SIMULATE_SEED_MAX = (SEED_MAX - 99) // 100

#: The networks the package ships (an export of the fine-tuning, see docs/training.md).
DEFAULT_NETWORKS = Path(__file__).resolve().parent / "weights" / "networks.pt"

#: The key of a ``networks.pt`` export that holds its :class:`AcquisitionSettings` (the other keys
#: are network records).
SETTINGS_KEY = "acquisition"

#: A capture: patterns (B, P, 3, h, w) drive values -> images (B, P, 3, H, W) linear radiance.
CaptureFn = Callable[[Tensor], Tensor]


# ---- settings and records ------------------------------------------------------------------


@dataclass(frozen=True)
class AcquisitionSettings:
    """How a set of networks acquires; training decides them, inference must use the same.

    Args:
        lpdf_from: where L_pdf comes from: "initializer" (the method), "uniform" (the paper's
            fixed-L_pdf ablation, "Diff. Init."), or "ground_truth" (training only: the true maps;
            acquisitions of such networks use the initializer's estimate, which it stands for).
        lpdf_stride: texel stride of the L_pdf quadrature (4: 0.9 s for 256 x 256 on 2 cores).
        use_spec: whether G_sc takes I^spec besides the images.
        lpdf_cell_order, lpdf_lobe_grid: the L_pdf quadrature's orders
            (:class:`~mitsvbrdf.render.quadrature.QuadratureSettings`); the defaults are the
            renderer's. L_pdf's error is dominated by the texel stride, not by these: at 64 px,
            stride 4, orders (1, 16) cost a fifth of (2, 32) for the same error
            (``benchmarks/lpdf_cost.py``, docs/benchmarks/lpdf_cost.md).
        resolution: texels a side of the materials the networks trained on (``data.size``); finer
            captures are reconstructed across the two grids (:mod:`mitsvbrdf.resolution`). None
            (exports written before it was recorded): every capture on its own grid.
    """

    lpdf_from: str = "initializer"
    lpdf_stride: int = 4
    use_spec: bool = True
    lpdf_cell_order: int = 2
    lpdf_lobe_grid: int = 32
    resolution: int | None = None

    LPDF_SOURCES = ("initializer", "uniform", "ground_truth")

    def __post_init__(self):
        if self.lpdf_from not in self.LPDF_SOURCES:
            raise MitsvbrdfError(f"lpdf_from must be one of {', '.join(self.LPDF_SOURCES)}, got {self.lpdf_from!r}")
        if isinstance(self.lpdf_stride, bool) or not isinstance(self.lpdf_stride, int) or self.lpdf_stride < 1:
            raise MitsvbrdfError(f"lpdf_stride must be an integer >= 1, got {self.lpdf_stride!r}")
        if not isinstance(self.use_spec, bool):
            raise MitsvbrdfError(f"use_spec must be true or false, got {self.use_spec!r}")
        for name, lo in (("lpdf_cell_order", 1), ("lpdf_lobe_grid", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise MitsvbrdfError(f"{name} must be an integer >= {lo}, got {v!r}")
        r = self.resolution
        if r is not None and (isinstance(r, bool) or not isinstance(r, int) or r < 1):
            raise MitsvbrdfError(f"resolution must be an integer >= 1 or absent, got {r!r}")

    @property
    def lpdf_quadrature(self) -> QuadratureSettings:
        return QuadratureSettings(cell_order=self.lpdf_cell_order, lobe_grid=self.lpdf_lobe_grid)

    def record(self) -> dict:
        """Plain data for a networks file (what :meth:`from_record` reads back)."""
        return asdict(self)

    @classmethod
    def from_record(cls, rec: dict | None, where: str = "networks file", **defaults) -> "AcquisitionSettings":
        """Settings from a networks file's record; keys it lacks (an older file) take ``defaults``,
        then the class defaults."""
        rec = {} if rec is None else rec
        if not isinstance(rec, dict):
            raise NetworkFileError(f"{where}: acquisition settings must be a table, got {type(rec).__name__}")
        unknown = sorted(set(rec) - {f.name for f in fields(cls)})
        if unknown:
            raise NetworkFileError(f"{where}: unknown acquisition settings {unknown}")
        try:
            return cls(**{**defaults, **rec})
        except MitsvbrdfError as e:
            raise NetworkFileError(f"{where}: {e}") from e


@dataclass
class Acquisition:
    """What one acquisition produced (tensors without batch dimension for one material).

    Attributes:
        patterns: (P, 3, h, w) drive values shown, L_0 first (a black pattern for the flash).
        images: (P, 3, H, W) linear radiance captured under them.
        svbrdf: the reconstruction (B = 1).
        lpdf: (1, h, w) the importance distribution the adaptive patterns were predicted from
            (None for a baseline).
        initial: the initializer's estimate, whose normal and roughness drive L_pdf (None for a
            baseline).
    """

    patterns: Tensor
    images: Tensor
    svbrdf: SVBRDF
    lpdf: Tensor | None = None
    initial: SVBRDF | None = None


@dataclass
class Prediction:
    """:func:`predict`'s output for a batch: ``patterns`` (B, 4, 3, h, w) in [0, 1], ``lpdf``
    (B, 1, h, w), ``initial`` the initializer's estimate, ``normal`` (B, 3, H, W) and
    ``roughness`` (B, 1, H, W) G_l's inverse estimates (the inverse-importance loss's input)."""

    patterns: Tensor
    lpdf: Tensor
    initial: SVBRDF
    normal: Tensor | None = None
    roughness: Tensor | None = None


# ---- the shared steps ----------------------------------------------------------------------


def maps_to_svbrdf(encoded: Tensor) -> SVBRDF:
    """Network output (B, 10, H, W) -> a valid SVBRDF: values clipped to [0, 1] and the encoded
    normal's z kept above 1/2, so that every decoded normal faces up."""
    t = encoded.clamp(0.0, 1.0)
    t = torch.cat([t[:, :2], t[:, 2:3].clamp_min(0.5 + 1e-3), t[:, 3:]], 1)
    return SVBRDF.from_encoded(t)


def initial_estimate(initializer: torch.nn.Module, i0: Tensor, l0: Tensor | None, rig: Rig) -> Tensor:
    """The initializer's encoded maps (B, 10, H, W) from I_0 (B, 3, H, W) on its texel grid. An
    initializer whose ``diffuse_ratio`` attribute is true is also given L_0's flat-Lambertian
    irradiance L_0^d (Eq. 4) on that grid, which needs ``l0`` (3, h, w); others ignore ``l0``.
    Differentiable in the initializer and in ``l0`` (the init stage trains both)."""
    if not getattr(initializer, "diffuse_ratio", False):
        return initializer(i0)
    if l0 is None:
        raise MitsvbrdfError("this initializer takes I_0 over L_0's irradiance and needs L_0")
    return initializer(i0, irradiance=diffuse_irradiance(l0[None], rig, tuple(i0.shape[-2:])))


def predict(initializer: torch.nn.Module, lighting: torch.nn.Module, i0: Tensor, rig: Rig,
            settings: AcquisitionSettings, *, l0: Tensor | None = None,
            ground_truth: SVBRDF | None = None) -> Prediction:
    """I_0 (B, 3, H, W) under ``l0`` (3, h, w) -> the initializer's estimate -> L_pdf -> G_l's
    adaptive patterns.

    The estimate and L_pdf carry no gradients; G_l's outputs do (training optimises G_l through
    them). ``l0`` is needed by an initializer with the diffuse-ratio input only
    (:func:`initial_estimate`), ``ground_truth`` for ``lpdf_from = "ground_truth"`` only.
    """
    with torch.no_grad():
        initial = maps_to_svbrdf(initial_estimate(initializer, i0, l0, rig))
        if settings.lpdf_from == "uniform":
            lpdf = torch.ones(i0.shape[0], 1, *rig.lcd_cells, device=i0.device, dtype=i0.dtype)
        else:
            source = initial
            if settings.lpdf_from == "ground_truth":
                if ground_truth is None:
                    raise MitsvbrdfError("lpdf_from = 'ground_truth' needs the ground-truth material")
                source = ground_truth
            lpdf = importance(source.normal, source.roughness, rig, texel_stride=settings.lpdf_stride,
                              settings=settings.lpdf_quadrature)
    out = lighting(i0, lpdf)
    return Prediction(out.patterns.clamp(0, 1), lpdf, initial, getattr(out, "normal", None),
                      getattr(out, "roughness", None))


def map_predictor(reconstructor: torch.nn.Module, patterns: Tensor, rig: Rig, *,
                  use_spec: bool) -> Callable[[Tensor], Tensor]:
    """G_sc as a function of captures alone, on whatever texel grid they come: ``run(images
    (B, P, 3, h, w)) -> (B, 10, h, w)`` encoded maps, for images under ``patterns`` (B, P, 3, h', w')
    or (P, 3, h', w'): ``reconstructor(images, I^spec)`` with I^spec separated from the images
    (Eq. 5), or ``reconstructor(images, None)`` without ``use_spec``; a G_sc built with
    ``diffuse_ratio`` also gets the patterns' irradiance L^d on that grid, which I^spec shares. L^d
    is computed once per grid (a fifth of a 64 px run's time; the resolution transfer runs G_sc up
    to 17 times on one grid)."""
    ratio = getattr(reconstructor, "diffuse_ratio", False)
    irradiance: dict[tuple, Tensor] = {}  # L^d by grid: the texel-phase runs share the coarse grid's

    def run(imgs: Tensor) -> Tensor:
        p = patterns.to(imgs.device, imgs.dtype)
        ld = None
        if ratio or use_spec:
            key = (tuple(imgs.shape[-2:]), imgs.device, imgs.dtype)
            if key not in irradiance:
                irradiance[key] = diffuse_irradiance(p, rig, imgs.shape[-2:])
            ld = irradiance[key]
        spec = separate_specular(imgs, p, rig, irradiance=ld) if use_spec else None
        return reconstructor(imgs, spec, irradiance=ld) if ratio else reconstructor(imgs, spec)

    return run


def reconstruct_maps(reconstructor: torch.nn.Module, images: Tensor, patterns: Tensor, rig: Rig, *,
                     use_spec: bool, resolution: int | None = None, transfer: str = DEFAULT_TRANSFER) -> Tensor:
    """G_sc (:func:`map_predictor`) on captures (B, P, 3, H, W) under ``patterns``. A capture finer
    than G_sc's training grid ``resolution`` is reconstructed across both grids in ``transfer`` mode
    (:func:`mitsvbrdf.resolution.reconstruct_across`; None: on its own grid). Returns its
    (B, 10, H, W) encoded maps."""
    return reconstruct_across(map_predictor(reconstructor, patterns, rig, use_spec=use_spec), images, resolution,
                              transfer)


def _check_use_spec(reconstructor: torch.nn.Module, use_spec: bool, where: str = "G_sc") -> None:
    built = getattr(reconstructor, "use_spec", None)
    if built is not None and built != use_spec:
        raise MitsvbrdfError(f"{where} was built with use_spec={built}, the acquisition settings say {use_spec}")


def size_multiple(*modules: torch.nn.Module) -> int:
    """The least common multiple of the input-size factors of every U-Net encoder in ``modules``
    (1 when there is none): H and W of their inputs must be multiples of it."""
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


def rendered_capture(svbrdf: SVBRDF, rig: Rig, *, method: str = "mitsuba", spp: int = 64, seed: int = 0,
                     noise: Callable[[Tensor, torch.Generator], Tensor] | None = None) -> CaptureFn:
    """A simulated capture of ``svbrdf`` through a renderer, with an optional noise model
    ``noise(images, generator)``: call k (1, 2, ...) renders with seed ``seed * 100 + k``."""
    check_int("seed", seed, 0, SIMULATE_SEED_MAX)
    g = torch.Generator(device=svbrdf.device).manual_seed(seed)
    step = iter(range(1, 100))

    def capture(patterns: Tensor) -> Tensor:
        with torch.no_grad():
            imgs = render(svbrdf, patterns, rig, method=method, spp=spp, seed=seed * 100 + next(step))
        return imgs if noise is None else noise(imgs, g)

    return capture


# ---- the adaptive method -------------------------------------------------------------------


class AdaptiveAcquisition(torch.nn.Module):
    """The adaptive acquisition with injected networks (module docstring), step by step:
    :attr:`l0` -> :meth:`predict_patterns` (I_0) -> :meth:`all_patterns` -> :meth:`reconstruct`;
    :meth:`acquire` runs them around a capture function, :meth:`simulate` around a renderer.

    Args:
        l0, initializer, lighting, reconstructor: see the module docstring.
        rig: the capture rig (L_pdf and the separation need its geometry and display model).
        settings: how the networks were trained (:class:`AcquisitionSettings`).
        transfer: how a capture finer than ``settings.resolution`` is reconstructed, one of
            :data:`mitsvbrdf.resolution.TRANSFER_MODES` (default "fused").
    """

    def __init__(self, l0: Tensor, initializer: torch.nn.Module, lighting: torch.nn.Module,
                 reconstructor: torch.nn.Module, rig: Rig, settings: AcquisitionSettings | None = None,
                 transfer: str = DEFAULT_TRANSFER):
        super().__init__()
        self.transfer = check_transfer(transfer)
        settings = settings or AcquisitionSettings()
        if settings.lpdf_from == "ground_truth":  # no ground truth at acquisition time
            settings = replace(settings, lpdf_from="initializer")
        _check_use_spec(reconstructor, settings.use_spec)
        h, w = rig.lcd_cells
        if tuple(l0.shape) != (3, h, w):
            raise ValueError(f"l0 must be (3, {h}, {w}) for this rig, got {tuple(l0.shape)}")
        self.register_buffer("l0", l0.detach().clone())
        self.initializer, self.lighting, self.reconstructor = initializer, lighting, reconstructor
        self.rig, self.settings = rig, settings

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
        """I_0 (B, 3, H, W) -> (adaptive patterns (B, 4, 3, h, w), L_pdf (B, 1, h, w), initial
        SVBRDF (B, H, W)); predicted on the working grid of the transfer mode."""
        p = predict(self.initializer, self.lighting, prediction_input(i0, self.settings.resolution, self.transfer),
                    self.rig, self.settings, l0=self.l0)
        return p.patterns, p.lpdf, p.initial.resized(tuple(i0.shape[-2:]))

    @torch.no_grad()
    def reconstruct(self, images: Tensor, patterns: Tensor) -> SVBRDF:
        """Images (B, 5, 3, H, W) under patterns (B, 5, 3, h, w) -> the reconstructed SVBRDF."""
        return maps_to_svbrdf(reconstruct_maps(self.reconstructor, images, patterns, self.rig,
                                               use_spec=self.settings.use_spec, resolution=self.settings.resolution,
                                               transfer=self.transfer))

    def all_patterns(self, adaptive: Tensor) -> Tensor:
        """L_0 prepended to adaptive patterns (B, 4, 3, h, w) -> (B, 5, 3, h, w)."""
        return prepend_pattern(self.l0, adaptive)

    @torch.no_grad()
    def acquire(self, capture: CaptureFn, batch: int = 1) -> Acquisition | list[Acquisition]:
        """Run the acquisition with ``capture`` (a renderer or a device): show L_0, predict, show
        the 4 adaptive patterns, reconstruct. One :class:`Acquisition` per material."""
        l0 = self.l0[None, None].expand(batch, 1, *self.l0.shape)
        i0 = capture(l0)[:, 0]
        adaptive, lpdf, initial = self.predict_patterns(i0)
        rest = capture(adaptive)
        patterns = self.all_patterns(adaptive)
        images = torch.cat([i0[:, None], rest], 1)
        svbrdf = self.reconstruct(images, patterns)
        out = [Acquisition(patterns[b], images[b], svbrdf[b], lpdf[b], initial[b]) for b in range(batch)]
        return out[0] if batch == 1 else out

    def simulate(self, svbrdf: SVBRDF, method: str = "mitsuba", spp: int = 64, seed: int = 0,
                 noise=None) -> Acquisition | list[Acquisition]:
        """Acquire ``svbrdf`` (B materials) through a renderer (:func:`rendered_capture`)."""
        self.check_resolution(svbrdf.resolution)
        capture = rendered_capture(svbrdf, self.rig, method=method, spp=spp, seed=seed, noise=noise)
        return self.acquire(capture, batch=svbrdf.batch_size)


# ---- the baselines -------------------------------------------------------------------------


class FixedAcquisition(torch.nn.Module):
    """A baseline: the same ``patterns`` (P, 3, h, w) for every material, then G_sc.

    Its simulated capture renders all patterns in one pass with the seed itself (not per step).
    ``resolution`` and ``transfer`` are :class:`AdaptiveAcquisition`'s (G_sc's training grid, and
    how finer captures are reconstructed).
    """

    def __init__(self, patterns: Tensor, reconstructor: torch.nn.Module, rig: Rig, *, use_spec: bool,
                 resolution: int | None = None, transfer: str = DEFAULT_TRANSFER):
        super().__init__()
        self.resolution, self.transfer = resolution, check_transfer(transfer)
        if tuple(patterns.shape[1:]) != (3, *rig.lcd_cells):
            raise MitsvbrdfError(f"patterns {tuple(patterns.shape[1:])} do not fit this rig's LCD "
                                 f"{(3, *rig.lcd_cells)}")
        _check_use_spec(reconstructor, use_spec)
        self.register_buffer("patterns", patterns.detach().clone())
        self.reconstructor, self.rig, self.use_spec = reconstructor, rig, use_spec

    @torch.no_grad()
    def acquire(self, capture: CaptureFn) -> Acquisition:
        images = capture(self.patterns[None])
        maps = reconstruct_maps(self.reconstructor, images, self.patterns, self.rig, use_spec=self.use_spec,
                                resolution=self.resolution, transfer=self.transfer)
        return Acquisition(self.patterns, images[0], maps_to_svbrdf(maps))

    def simulate(self, svbrdf: SVBRDF, method: str = "mitsuba", spp: int = 64, seed: int = 0) -> Acquisition:
        return self.acquire(lambda p: render(svbrdf, p[0], self.rig, method=method, spp=spp, seed=seed))


class FlashAcquisition(torch.nn.Module):
    """The flash baseline: one image under ``flash`` (a :class:`mitsvbrdf.relight.FlashLight`), then
    ``reconstructor(images (1, 1, 3, H, W))``. Its record shows a black LCD pattern: the LCD is off.
    ``resolution`` and ``transfer`` as for :class:`FixedAcquisition`."""

    def __init__(self, flash: torch.nn.Module, reconstructor: torch.nn.Module, rig: Rig, *,
                 resolution: int | None = None, transfer: str = DEFAULT_TRANSFER):
        super().__init__()
        self.flash, self.reconstructor, self.rig = flash, reconstructor, rig
        self.resolution, self.transfer = resolution, check_transfer(transfer)

    @torch.no_grad()
    def simulate(self, svbrdf: SVBRDF, **_ignored) -> Acquisition:
        images = self.flash(svbrdf, self.rig)
        dark = torch.zeros(1, 3, *self.rig.lcd_cells)
        maps = reconstruct_across(self.reconstructor, images, self.resolution, self.transfer)
        return Acquisition(dark, images[0], maps_to_svbrdf(maps))


# ---- networks files ------------------------------------------------------------------------

ADAPTIVE_NETWORKS = ("l0", "initializer", "lighting", "svbrdf")


def read_networks(path: str | Path, what: str = "networks", hint: str = "") -> tuple[dict, dict | None]:
    """({name: network record}, the settings record or None) of a ``networks.pt`` export."""
    recs = read_network_file(path, what, hint)
    if not isinstance(recs, dict):
        raise NetworkFileError(f"{path}: not a stage's export of networks (a {type(recs).__name__})")
    recs = dict(recs)
    return recs, recs.pop(SETTINGS_KEY, None)


def load_adaptive(path: str | Path, rig: Rig, *, lpdf_from: str | None = None,
                  transfer: str = DEFAULT_TRANSFER) -> AdaptiveAcquisition:
    """The adaptive acquisition from a ``networks.pt`` export of stage 2 or the fine-tuning, with
    the settings it was trained with (files without them: L_pdf from the initializer at stride 4,
    ``use_spec`` as G_sc was built). ``lpdf_from`` overrides the file's source of L_pdf;
    ``transfer`` is :class:`AdaptiveAcquisition`'s."""
    recs, stored = read_networks(path, "networks", " (train the stages, see docs/training.md)")
    if any(k not in recs for k in ADAPTIVE_NETWORKS):
        raise NetworkFileError(f"{path}: an acquisition needs networks {list(ADAPTIVE_NETWORKS)}, the file has "
                               f"{sorted(recs)} (use the export of stage2 or finetune)")
    nets = {k: network_from_record(recs[k], f"{path}: {k}").eval() for k in ADAPTIVE_NETWORKS}
    settings = AcquisitionSettings.from_record(stored, str(path), use_spec=getattr(nets["svbrdf"], "use_spec", True))
    if lpdf_from is not None:
        settings = replace(settings, lpdf_from=lpdf_from)
    with torch.no_grad():
        l0 = nets["l0"]()[0]
    try:
        return AdaptiveAcquisition(l0, nets["initializer"], nets["lighting"], nets["svbrdf"], rig, settings, transfer)
    except MitsvbrdfError as e:
        raise NetworkFileError(f"{path}: {e}") from e


def load_baseline(path: str | Path, rig: Rig, *,
                  transfer: str = DEFAULT_TRANSFER) -> FixedAcquisition | FlashAcquisition:
    """A baseline from the ``networks.pt`` export of a ``fixed`` training stage: its pattern group
    (fixed or learned) or its flash, and its G_sc, reconstructing finer captures in ``transfer``
    mode. Raises NetworkFileError for other files."""
    recs, stored = read_networks(path, "baseline networks")
    if "svbrdf" not in recs or not ({"patterns", "flash"} & set(recs)):
        raise NetworkFileError(f"{path}: a baseline needs networks 'svbrdf' and 'patterns' (or 'flash'), "
                               f"the file has {sorted(recs)} (use the export of a 'fixed' stage)")
    net = network_from_record(recs["svbrdf"], f"{path}: svbrdf").eval()
    settings = AcquisitionSettings.from_record(stored, str(path), use_spec=getattr(net, "use_spec", True))
    if "flash" in recs:
        return FlashAcquisition(network_from_record(recs["flash"], f"{path}: flash"), net, rig,
                                resolution=settings.resolution, transfer=transfer)
    pats = network_from_record(recs["patterns"], f"{path}: patterns")().detach()
    try:
        return FixedAcquisition(pats, net, rig, use_spec=settings.use_spec, resolution=settings.resolution,
                                transfer=transfer)
    except MitsvbrdfError as e:
        raise NetworkFileError(f"{path}: {e}") from e

