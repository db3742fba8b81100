"""The training stages (paper Sec. 3.3, 3.5 and Sec. 5 "Implementation details").

Each stage is a module whose ``forward(batch, seed)`` renders the batch's captures through the
configured renderer (Mitsuba by default, so G_l's gradients come through physically based
rendering) and returns its scalar losses; ``"loss"`` is the one minimised.

* ``init``: learned L_0 + initializer, L1 on all maps (also the single-pattern "LPL" baseline).
* ``stage1``: G_l + G_p (per-pixel), L = lambda_c L_c + lambda_inv L_inv + lambda_r L_r, with L_0
  and the initializer frozen (from ``init``).
* ``stage2``: G_l (from stage 1) + G_sc with I^spec, lambda_inv = 0.05.
* ``finetune``: G_sc alone on captures with G_l's patterns (G_l frozen), e.g. at higher spp.
  ``model.use_spec = false`` in stage 2 and fine-tuning gives the paper's Table 3 "Adaptive"
  (G_sc a single-encoder NAFNet on the images, like the baselines).
* ``fixed``: G_sc on a pattern group that is the same for every material (the evaluation's
  baselines): a named or stored group; ``learn_patterns`` optimises the group jointly with G_sc
  through the renderer (5 patterns: "Optimized"/LPL+; 1 pattern: LPL); ``light = "flash"``
  replaces the LCD by a point light at the camera (the flash baseline).

Tensors: maps (B, C, H, W); patterns (B, P, 3, h, w) drive values; images (B, P, 3, H, W) linear.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, ClassVar

import torch
from torch import Tensor, nn

from ..acquisition import AcquisitionSettings, initial_estimate, maps_to_svbrdf, predict, reconstruct_maps
from ..errors import MitsvbrdfError
from ..importance import importance
from ..losses import PLAIN_MAP_WEIGHTS, importance_consistency_loss, inverse_importance_loss, map_l1
from ..nets import (Initializer, LearnedPattern, LightingPredictor, PatternSet, PointPredictor, SVBRDFPredictor,
                    network_from_record, with_diffuse_ratio)
from ..patterns import load_pattern, load_patterns, prepend_pattern
from ..relight import FlashLight
from ..render import render
from ..rig import Rig
from ..separation import diffuse_irradiance
from ..svbrdf import SVBRDF


@dataclass
class RenderSettings:
    """How a stage renders its captures: ``method`` of :func:`mitsvbrdf.render`, ``spp``, and an
    optional noise model ``noise(images, generator) -> images``."""

    method: str = "mitsuba"
    spp: int = 4
    noise: Callable[[Tensor, torch.Generator], Tensor] | None = None
    ltc_mode: str = "exact"


#: the model option that asks a network of each class for the diffuse-ratio inputs; a pretrained
#: network without them is widened (:func:`mitsvbrdf.nets.with_diffuse_ratio`)
RATIO_OPTIONS = {SVBRDFPredictor: "diffuse_ratio", Initializer: "initializer_diffuse_ratio"}


class TrainingStage(nn.Module):
    """Base class: rendering, pretrained networks, export. Subclasses set ``name``, ``Model``,
    ``Loss``, build their networks in ``__init__`` and implement ``forward``."""

    name: ClassVar[str]
    Model: ClassVar[type]
    Loss: ClassVar[type]
    #: networks this stage needs from an earlier stage's export, and whether they stay frozen
    PRETRAINED: ClassVar[dict[str, bool]] = {}

    def __init__(self, model, loss, render_settings: RenderSettings, rig: Rig):
        super().__init__()
        self.model_cfg, self.loss_cfg, self.render_cfg, self.rig = model, loss, render_settings, rig
        self.nets = nn.ModuleDict()

    # -- networks ---------------------------------------------------------------------------
    def networks(self) -> dict[str, nn.Module]:
        return dict(self.nets.items())

    def load_pretrained(self, records: dict[str, dict]) -> None:
        """Replace the networks named in ``PRETRAINED`` by those of an earlier stage's export
        ({name: network record}); frozen ones get requires_grad False."""
        missing = [n for n in self.PRETRAINED if n not in records]
        if missing:
            raise MitsvbrdfError(f"stage {self.name!r} needs pretrained networks {missing}; the file has "
                                 f"{sorted(records)}")
        for n, frozen in self.PRETRAINED.items():
            self._adopt(n, records[n], frozen)

    def warm_start(self, records: dict[str, dict]) -> None:
        """Start the networks this stage would train from scratch from an export's, where it has
        them (continuing a chain from shipped weights); the file's architecture then wins over the
        config's, and they stay trainable."""
        scratch = [n for n in self.nets if n not in self.PRETRAINED]
        started = [n for n in scratch if n in records]
        if not started:
            raise MitsvbrdfError(f"pretrained.warm_start: the file has none of the networks stage {self.name!r} "
                                 f"trains ({sorted(scratch)}); it has {sorted(records)}")
        for n in started:
            self._adopt(n, records[n], frozen=False)

    def _adopt(self, name: str, record: dict, frozen: bool) -> None:
        net = network_from_record(record, f"pretrained network {name!r}")
        if name in self.nets and type(net) is not type(self.nets[name]):
            raise MitsvbrdfError(f"pretrained network {name!r} is a {type(net).__name__}, "
                                 f"stage {self.name!r} needs a {type(self.nets[name]).__name__}")
        option = RATIO_OPTIONS.get(type(net))
        if option and getattr(self.model_cfg, option, False):
            net = with_diffuse_ratio(net)  # trained without the option: the new inputs start at zero
        net.requires_grad_(not frozen)
        self.nets[name] = net

    def acquisition_settings(self) -> AcquisitionSettings | None:
        """How an acquisition must use this stage's networks (saved with them by the export);
        None for a stage whose networks acquire nothing by themselves."""
        return None

    def param_groups(self, lr: float) -> list[dict]:
        """The optimiser's parameter groups at base learning rate ``lr``: every trainable parameter
        at ``lr`` (stages with parameters that want another rate override this)."""
        return [{"params": [p for p in self.parameters() if p.requires_grad], "lr": lr}]

    # -- rendering --------------------------------------------------------------------------
    def capture(self, batch: SVBRDF, patterns: Tensor, seed: int, generator: torch.Generator) -> Tensor:
        cfg = self.render_cfg
        extra = {"mode": cfg.ltc_mode} if cfg.method == "ltc" else {}
        return self.sensor(render(batch, patterns, self.rig, method=cfg.method, spp=cfg.spp, seed=seed, **extra),
                           generator)

    def sensor(self, images: Tensor, generator: torch.Generator) -> Tensor:
        """The configured sensor noise on rendered images (unchanged without a noise model)."""
        return images if self.render_cfg.noise is None else self.render_cfg.noise(images, generator)

    def first_image(self, batch: SVBRDF, seed: int, g: torch.Generator) -> tuple[Tensor, Tensor]:
        """(L_0 (3, h, w), I_0 (B, 3, H, W))."""
        l0 = self.nets["l0"]()[0]
        return l0, self.capture(batch, l0[None], seed, g)[:, 0]


def _generator(seed: int, device) -> torch.Generator:
    return torch.Generator(device=device).manual_seed(seed)


@dataclass
class LpdfQuadratureModel:
    """How a stage computes L_pdf: texel stride and quadrature orders (:class:`AcquisitionSettings`)."""

    lpdf_stride: int = 4
    lpdf_cell_order: int = 2
    lpdf_lobe_grid: int = 32

    def lpdf(self, svbrdf: SVBRDF, rig: Rig) -> Tensor:
        """L_pdf (B, 1, h, w) of ``svbrdf``'s normal and roughness maps."""
        settings = AcquisitionSettings(lpdf_stride=self.lpdf_stride, lpdf_cell_order=self.lpdf_cell_order,
                                       lpdf_lobe_grid=self.lpdf_lobe_grid)
        return importance(svbrdf.normal, svbrdf.roughness, rig, texel_stride=settings.lpdf_stride,
                          settings=settings.lpdf_quadrature)


# ---- init ----------------------------------------------------------------------------------


@dataclass
class InitModel(LpdfQuadratureModel):
    initializer_width: int = 16
    initializer_blocks: list[int] = field(default_factory=lambda: [1, 1, 1])
    # false: L_0 keeps its starting values (a warm start's pattern, else uniform 0.9) and only the
    # initializer trains; continuing the initializer of shipped networks this way leaves I_0, and
    # so every later stage's input, as those networks were trained with
    train_l0: bool = True
    # L_0's own learning rate (0: train.lr). Behind a sigmoid at its uniform start (drive 0.9, slope
    # 0.09) and with one noisy render gradient a step, at train.lr it barely moves: the shipped L_0
    # is 0.89 +- 0.01 after its init stage, nearly uniform light, under which a normal's shading is
    # a few per cent of I_0 (docs/training.md, "L_0's rate and start")
    pattern_lr: float = 0.0
    # where L_0 starts (and stays, with train_l0 false): "uniform" (drive 0.9) or "grey" (0.5), or one
    # pattern of a family or file, "NAME[k]" (patterns.load_pattern; e.g. "colorgrad[1]", red rising
    # along u and green along v, so a slope's direction shades I_0). A warm start's L_0 replaces it.
    l0_start: str = "uniform"
    # the initializer also sees I_0 over L_0's flat-Lambertian irradiance (Initializer's
    # diffuse_ratio; not in the paper); a warm-started initializer without it is widened, its new
    # inputs starting at zero
    initializer_diffuse_ratio: bool = False


@dataclass
class InitLoss:
    maps: float = 1.0
    map_weights: list[float] = field(default_factory=lambda: list(PLAIN_MAP_WEIGHTS))
    # L1 between the L_pdf of the initializer's estimate and that of the truth (not in the paper).
    # Per-texel L1 lets an unsure initializer hedge to flat normals and trade the missing tilt for
    # roughness; L_pdf, all the later stages take from it, then cannot tell a bumpy material from
    # a rough dielectric (docs/benchmarks/pattern_gallery.md). 0: off, and not computed.
    lpdf: float = 0.0


class InitStage(TrainingStage):
    name, Model, Loss = "init", InitModel, InitLoss

    def __init__(self, model: InitModel, loss: InitLoss, render_settings: RenderSettings, rig: Rig):
        super().__init__(model, loss, render_settings, rig)
        if not model.pattern_lr >= 0:
            raise MitsvbrdfError(f"model.pattern_lr must be >= 0, got {model.pattern_lr}")
        start = model.l0_start if model.l0_start in ("uniform", "grey") else load_pattern(model.l0_start, *rig.lcd_cells)
        self.nets["l0"] = LearnedPattern(rig.lcd_cells, init=start).requires_grad_(model.train_l0)
        self.nets["initializer"] = Initializer(model.initializer_width, tuple(model.initializer_blocks),
                                               diffuse_ratio=model.initializer_diffuse_ratio)

    def warm_start(self, records: dict[str, dict]) -> None:
        super().warm_start(records)
        self.nets["l0"].requires_grad_(self.model_cfg.train_l0)

    def param_groups(self, lr: float) -> list[dict]:
        l0 = [p for p in self.nets["l0"].parameters() if p.requires_grad]
        if not l0 or not self.model_cfg.pattern_lr:
            return super().param_groups(lr)
        rest = [p for p in self.parameters() if p.requires_grad and all(p is not q for q in l0)]
        return [{"params": rest, "lr": lr}, {"params": l0, "lr": self.model_cfg.pattern_lr}]

    def forward(self, batch: SVBRDF, seed: int) -> dict[str, Tensor]:
        g = _generator(seed, batch.device)
        l0, i0 = self.first_image(batch, seed, g)
        pred = initial_estimate(self.nets["initializer"], i0, l0, self.rig)
        l_maps = map_l1(pred, batch.encoded(), self.loss_cfg.map_weights)
        out = {"loss": self.loss_cfg.maps * l_maps, "maps": l_maps}
        if self.loss_cfg.lpdf:
            with torch.no_grad():
                target = self.model_cfg.lpdf(batch, self.rig)
            # the estimate as acquisitions decode it (predict), so the loss sees the L_pdf they use
            l_lpdf = (self.model_cfg.lpdf(maps_to_svbrdf(pred), self.rig) - target).abs().mean()
            out["lpdf"] = l_lpdf
            out["loss"] = out["loss"] + self.loss_cfg.lpdf * l_lpdf
        return out


# ---- stage 1 and 2 -------------------------------------------------------------------------


@dataclass
class AdaptiveModel(LpdfQuadratureModel):
    lighting_width: int = 12
    lighting_blocks: list[int] = field(default_factory=lambda: [1, 1, 1])
    point_hidden: int = 64
    point_layers: int = 3
    svbrdf_width: int = 16
    svbrdf_blocks: list[int] = field(default_factory=lambda: [1, 1, 1])
    lpdf_from: str = "initializer"   # "initializer" | "ground_truth" | "uniform" (Diff. Init. ablation)
    use_spec: bool = True            # G_sc's second encoder on I^spec (False: Table 3's "Adaptive")
    diffuse_ratio: bool = False      # G_sc also sees each image over its L^d (not in the paper; docs/training.md)


@dataclass
class AdaptiveLoss:
    consistency: float = 1.0
    inverse: float = 0.5
    reconstruction: float = 1.0
    map_weights: list[float] = field(default_factory=lambda: list(PLAIN_MAP_WEIGHTS))


@dataclass
class Stage2Loss(AdaptiveLoss):
    inverse: float = 0.05


class AdaptiveStage(TrainingStage):
    """Shared part of stages 1 and 2: I_0 -> L_pdf -> G_l -> the adaptive captures."""

    PRETRAINED = {"l0": True, "initializer": True}

    def __init__(self, model: AdaptiveModel, loss, render_settings: RenderSettings, rig: Rig):
        super().__init__(model, loss, render_settings, rig)
        if model.lpdf_from not in ("initializer", "ground_truth", "uniform"):
            raise MitsvbrdfError(f"model.lpdf_from must be initializer, ground_truth or uniform, got {model.lpdf_from!r}")
        self.nets["l0"] = LearnedPattern(rig.lcd_cells)
        self.nets["initializer"] = Initializer()
        self.nets["lighting"] = LightingPredictor(4, rig.lcd_cells, model.lighting_width, tuple(model.lighting_blocks))

    def acquisition_settings(self) -> AcquisitionSettings:
        cfg = self.model_cfg
        # G_sc (built here or pretrained) knows whether it takes I^spec; stage 1 has none
        use_spec = self.nets["svbrdf"].use_spec if "svbrdf" in self.nets else cfg.use_spec
        return AcquisitionSettings(cfg.lpdf_from, cfg.lpdf_stride, use_spec, cfg.lpdf_cell_order, cfg.lpdf_lobe_grid)

    def adaptive_captures(self, batch: SVBRDF, seed: int):
        """The acquisition's steps (:func:`mitsvbrdf.acquisition.predict`) with this stage's
        renderer for the captures: (patterns (B, 5, 3, h, w), images (B, 5, 3, H, W), losses)."""
        g = _generator(seed, batch.device)
        with torch.no_grad():
            l0, i0 = self.first_image(batch, seed, g)
        pred = predict(self.nets["initializer"], self.nets["lighting"], i0, self.rig, self.acquisition_settings(),
                       l0=l0, ground_truth=batch)
        imgs = self.capture(batch, pred.patterns, seed + 1, g)
        patterns = prepend_pattern(l0.detach(), pred.patterns)
        images = torch.cat([i0[:, None], imgs], 1)
        losses = {"consistency": importance_consistency_loss(l0.detach(), pred.patterns, pred.lpdf),
                  "inverse": inverse_importance_loss(pred.normal, pred.roughness, batch.normal, batch.roughness)}
        return patterns, images, losses

    def reconstruct(self, images: Tensor, patterns: Tensor) -> Tensor:
        """G_sc's encoded maps (B, 10, H, W), as an acquisition computes them."""
        return reconstruct_maps(self.nets["svbrdf"], images, patterns, self.rig,
                                use_spec=self.nets["svbrdf"].use_spec)

    def total(self, losses: dict[str, Tensor]) -> dict[str, Tensor]:
        c = self.loss_cfg
        losses["loss"] = c.consistency * losses["consistency"] + c.inverse * losses["inverse"] + \
            c.reconstruction * losses["reconstruction"]
        return losses


class Stage1(AdaptiveStage):
    name, Model, Loss = "stage1", AdaptiveModel, AdaptiveLoss

    def __init__(self, model: AdaptiveModel, loss: AdaptiveLoss, render_settings: RenderSettings, rig: Rig):
        super().__init__(model, loss, render_settings, rig)
        self.nets["point"] = PointPredictor(5, rig.lcd_cells, model.point_hidden, model.point_layers)

    def forward(self, batch: SVBRDF, seed: int) -> dict[str, Tensor]:
        patterns, images, losses = self.adaptive_captures(batch, seed)
        irradiance = diffuse_irradiance(patterns, self.rig, batch.resolution)
        pred = self.nets["point"](images, irradiance, patterns)
        losses["reconstruction"] = map_l1(pred, batch.encoded(), self.loss_cfg.map_weights)
        return self.total(losses)


class Stage2(AdaptiveStage):
    name, Model, Loss = "stage2", AdaptiveModel, Stage2Loss
    PRETRAINED = {"l0": True, "initializer": True, "lighting": False}

    def __init__(self, model: AdaptiveModel, loss: AdaptiveLoss, render_settings: RenderSettings, rig: Rig):
        super().__init__(model, loss, render_settings, rig)
        self.nets["svbrdf"] = SVBRDFPredictor(5, model.svbrdf_width, tuple(model.svbrdf_blocks),
                                              use_spec=model.use_spec, diffuse_ratio=model.diffuse_ratio)

    def forward(self, batch: SVBRDF, seed: int) -> dict[str, Tensor]:
        patterns, images, losses = self.adaptive_captures(batch, seed)
        pred = self.reconstruct(images, patterns)
        losses["reconstruction"] = map_l1(pred, batch.encoded(), self.loss_cfg.map_weights)
        return self.total(losses)


class Finetune(Stage2):
    """G_sc alone on captures with the frozen G_l's patterns (paper: Mitsuba renderings)."""

    name = "finetune"
    PRETRAINED = {"l0": True, "initializer": True, "lighting": True, "svbrdf": False}

    def forward(self, batch: SVBRDF, seed: int) -> dict[str, Tensor]:
        with torch.no_grad():
            patterns, images, _ = self.adaptive_captures(batch, seed)
        rec = map_l1(self.reconstruct(images, patterns), batch.encoded(), self.loss_cfg.map_weights)
        return {"loss": self.loss_cfg.reconstruction * rec, "reconstruction": rec}


# ---- fixed-pattern baselines ---------------------------------------------------------------


@dataclass
class FixedModel:
    patterns: str = "monograd"   # a family name or a .npy/.pt/PNG file; with learn_patterns, the start
    learn_patterns: bool = False  # optimise the group with G_sc (LPL+ from 5 patterns, LPL from 1)
    light: str = "lcd"           # "lcd" | "flash" (one image under a point light at the camera)
    pattern_lr: float = 0.0      # learning rate of learned patterns (0: train.lr); they see weak, noisy gradients
    flash_intensity: float = 0.04  # W/sr, light = "flash"
    svbrdf_width: int = 16
    svbrdf_blocks: list[int] = field(default_factory=lambda: [1, 1, 1])
    use_spec: bool = False
    diffuse_ratio: bool = False


@dataclass
class FixedLoss:
    reconstruction: float = 1.0
    map_weights: list[float] = field(default_factory=lambda: list(PLAIN_MAP_WEIGHTS))


class FixedStage(TrainingStage):
    name, Model, Loss = "fixed", FixedModel, FixedLoss

    def __init__(self, model: FixedModel, loss: FixedLoss, render_settings: RenderSettings, rig: Rig):
        super().__init__(model, loss, render_settings, rig)
        if model.pattern_lr < 0:
            raise MitsvbrdfError(f"model.pattern_lr must be >= 0, got {model.pattern_lr}")
        if model.light not in ("lcd", "flash"):
            raise MitsvbrdfError(f"model.light must be 'lcd' or 'flash', got {model.light!r}")
        if model.light == "flash":
            if model.learn_patterns or model.use_spec or model.diffuse_ratio:
                raise MitsvbrdfError("model.light = 'flash' has no LCD patterns: learn_patterns, use_spec and "
                                     "diffuse_ratio must be false")
            self.nets["flash"] = FlashLight(model.flash_intensity)
            count = 1
        else:
            pats = load_patterns(model.patterns, *rig.lcd_cells)
            rig.check_patterns(pats)
            count = pats.shape[0]
            self.nets["patterns"] = PatternSet(count, rig.lcd_cells, learnable=model.learn_patterns)
            self.nets["patterns"].set(pats)
        self.nets["svbrdf"] = SVBRDFPredictor(count, model.svbrdf_width, tuple(model.svbrdf_blocks),
                                              use_spec=model.use_spec, diffuse_ratio=model.diffuse_ratio)

    def acquisition_settings(self) -> AcquisitionSettings:
        return AcquisitionSettings(use_spec=self.nets["svbrdf"].use_spec)

    def param_groups(self, lr: float) -> list[dict]:
        if not self.model_cfg.learn_patterns:
            return super().param_groups(lr)
        pats = list(self.nets["patterns"].parameters())
        return [{"params": list(self.nets["svbrdf"].parameters()), "lr": lr},
                {"params": pats, "lr": self.model_cfg.pattern_lr or lr}]

    def forward(self, batch: SVBRDF, seed: int) -> dict[str, Tensor]:
        g = _generator(seed, batch.device)
        if self.model_cfg.light == "flash":
            with torch.no_grad():
                images = self.sensor(self.nets["flash"](batch, self.rig), g)
            pred = self.nets["svbrdf"](images)
        else:
            pats = self.nets["patterns"]()
            # the renderer's gradients reach the patterns only when they are learned
            with torch.set_grad_enabled(self.model_cfg.learn_patterns):
                images = self.capture(batch, pats, seed, g)
            pred = reconstruct_maps(self.nets["svbrdf"], images, pats, self.rig, use_spec=self.nets["svbrdf"].use_spec)
        rec = map_l1(pred, batch.encoded(), self.loss_cfg.map_weights)
        return {"loss": self.loss_cfg.reconstruction * rec, "reconstruction": rec}


STAGES: dict[str, type[TrainingStage]] = {s.name: s for s in (InitStage, Stage1, Stage2, Finetune, FixedStage)}
