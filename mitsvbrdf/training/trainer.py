"""The training driver: ``mitsvbrdf train CONFIG`` (also under ``torchrun``).

One loop for every stage: Adam with cosine annealing, seeded; a progress bar with the loss and
it/s; ``metrics.csv`` and ``loss.png``; checkpoints every ``train.checkpoint_every`` steps, on
SIGINT/SIGTERM (at the next step boundary) and at the end, written atomically; ``--resume``
continues exactly where the checkpoint left off (same batches, same render seeds, same optimiser
state, hence the same parameters as an uninterrupted run). At the end the stage's networks are
exported to ``OUT/networks.pt`` ({name: network record}) for the next stage's ``[pretrained]``.

Data and seeds depend only on the global sample index and the step, never on the process: step
``k`` uses materials ``k * batch ... (k + 1) * batch - 1`` of the procedural stream, and under
DistributedDataParallel rank ``r`` of ``R`` takes its contiguous share of those and renders them
with seed ``(seed, k, r)``. With a deterministic renderer (``reference``) R processes therefore
reproduce one process with the whole batch; with Monte Carlo rendering they differ only in noise.
"""

from __future__ import annotations

import csv
import math
import os
import signal
import time
from pathlib import Path

import torch
import torch.distributed as dist

from ..errors import MitsvbrdfError
from ..nets import network_record
from ..nets.io import read_network_file
from ..rig import Rig
from ..sensor import SensorNoise
from .config import Config, config_table
from .stages import STAGES, RenderSettings, TrainingStage


class TrainingError(MitsvbrdfError):
    """A run that cannot start or continue (missing checkpoint, incompatible files)."""


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise TrainingError("train.device = 'cuda' but no CUDA device is available")
    return torch.device(name)


def make_dataset(cfg: Config):
    from ..data.datasets import MapFolderDataset, ProceduralDataset, StripDataset

    d = cfg.data
    if d.source == "procedural":
        return ProceduralDataset(d.length, d.size, seed=cfg.seed, families=d.families or None)
    if d.source == "strips":
        return StripDataset(d.root, crop=d.size)
    return MapFolderDataset(d.root, crop=d.size)


def step_seed(seed: int, step: int, rank: int) -> int:
    """Render/noise seed of a step on a rank (kept below 2^31 for every backend)."""
    return (seed * 1_000_003 + step * 101 + rank * 7919) % (2 ** 31 - 1)


class Trainer:
    """Runs one configured stage. ``rank``/``world`` come from torchrun's environment."""

    def __init__(self, cfg: Config, *, resume: bool = False, progress: bool = True, stop_after: int | None = None):
        self.cfg = cfg
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        if cfg.train.batch % self.world:
            raise TrainingError(f"train.batch = {cfg.train.batch} must be divisible by the {self.world} processes")
        self.device = _device(cfg.train.device)
        if self.world > 1 and not dist.is_initialized():
            dist.init_process_group("nccl" if self.device.type == "cuda" else "gloo")
        if self.device.type == "cuda" and self.world > 1:
            self.device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        self.out = Path(cfg.out)
        self.progress = progress and self.rank == 0
        self.stop_after = stop_after  # tests: stop as if killed after this many steps
        torch.manual_seed(cfg.seed)
        rig = Rig.from_scene(cfg.scene or None)
        noise = SensorNoise(**vars(cfg.render.noise))
        settings = RenderSettings(cfg.render.method, cfg.render.spp, noise if noise.active else None,
                                  cfg.render.ltc_mode)
        cls = STAGES[cfg.stage]
        self.stage: TrainingStage = cls(cfg.model, cfg.loss, settings, rig)
        if cls.PRETRAINED:
            self._load_pretrained()
        self.stage.to(self.device)
        groups = [g for g in self.stage.param_groups(cfg.train.lr) if g["params"]]
        if not groups:
            raise TrainingError(f"stage {cfg.stage!r} has nothing to train")
        self.opt = torch.optim.Adam(groups, lr=cfg.train.lr, weight_decay=cfg.train.weight_decay)
        self.sched = torch.optim.lr_scheduler.CosineAnnealingLR(self.opt, cfg.train.steps, eta_min=cfg.train.lr_min)
        self.model = self.stage
        if self.world > 1:
            self.model = torch.nn.parallel.DistributedDataParallel(
                self.stage, device_ids=[self.device.index] if self.device.type == "cuda" else None,
                find_unused_parameters=True)
        self.dataset = make_dataset(cfg)
        self.step = 0
        self.history: list[dict] = []
        self._stop = False
        if resume:
            self._load_checkpoint()
        if self.rank == 0:
            import json

            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "config.json").write_text(json.dumps(config_table(cfg), indent=1, default=str))

    # -- files ------------------------------------------------------------------------------
    @property
    def checkpoint_path(self) -> Path:
        return self.out / "checkpoint.pt"

    def _load_pretrained(self) -> None:
        path = Path(self.cfg.pretrained.networks)
        if not self.cfg.pretrained.networks or not path.exists():
            raise TrainingError(f"stage {self.cfg.stage!r} starts from an earlier stage's networks: set "
                                f"pretrained.networks (now {str(path)!r}, which does not exist)")
        self.stage.load_pretrained(read_network_file(path, "networks"))

    def _load_checkpoint(self) -> None:
        if not self.checkpoint_path.exists():
            raise TrainingError(f"--resume: no checkpoint at {self.checkpoint_path}")
        ck = torch.load(self.checkpoint_path, map_location=self.device, weights_only=False)
        if ck["config"]["stage"] != self.cfg.stage:
            raise TrainingError(f"--resume: {self.checkpoint_path} is a {ck['config']['stage']!r} run, "
                                f"the config trains {self.cfg.stage!r}")
        self.stage.load_state_dict(ck["stage"])
        self.opt.load_state_dict(ck["optimizer"])
        self.sched.load_state_dict(ck["scheduler"])
        torch.set_rng_state(ck["rng"])
        self.step = ck["step"]
        self.history = ck["history"]

    def save_checkpoint(self) -> None:
        if self.rank != 0:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        ck = {"stage": self.stage.state_dict(), "optimizer": self.opt.state_dict(),
              "scheduler": self.sched.state_dict(), "rng": torch.get_rng_state(), "step": self.step,
              "history": self.history, "config": config_table(self.cfg)}
        tmp = self.checkpoint_path.with_suffix(".tmp")
        torch.save(ck, tmp)
        os.replace(tmp, self.checkpoint_path)
        self._write_metrics()

    def export(self) -> Path:
        path = self.out / "networks.pt"
        if self.rank == 0:
            recs = {n: network_record(net) for n, net in self.stage.networks().items()}
            tmp = path.with_suffix(".tmp")
            torch.save(recs, tmp)
            os.replace(tmp, path)
        return path

    def _write_metrics(self) -> None:
        if not self.history:
            return
        keys = list(dict.fromkeys(k for h in self.history for k in h))
        with open(self.out / "metrics.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            w.writerows(self.history)
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5))
        steps = [h["step"] for h in self.history]
        for k in keys:
            if k not in ("step", "lr", "it_per_s", "seconds"):
                ax.plot(steps, [h.get(k, math.nan) for h in self.history], label=k)
        ax.set_xlabel("step")
        ax.set_yscale("log")
        ax.set_title(f"{self.cfg.stage}: {self.cfg.out}")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(self.out / "loss.png", dpi=100)
        plt.close(fig)

    # -- the loop ---------------------------------------------------------------------------
    def batch(self, step: int):
        """This rank's share of the materials of ``step`` (on the device)."""
        from ..data.datasets import collate_svbrdf

        b = self.cfg.train.batch // self.world
        start = step * self.cfg.train.batch + self.rank * b
        n = len(self.dataset)
        idx = [(start + i) % n for i in range(b)]
        fetch = getattr(self.dataset, "__getitems__", None)
        items = fetch(idx) if fetch else [self.dataset[i] for i in idx]
        return collate_svbrdf(items).to(self.device)

    def _handle(self, signum, frame) -> None:
        self._stop = True

    def run(self) -> dict:
        """Train to ``train.steps``; returns the last logged losses."""
        from tqdm import tqdm

        cfg = self.cfg.train
        old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
        bar = tqdm(total=cfg.steps, initial=self.step, desc=self.cfg.stage, disable=not self.progress)
        t0, last = time.perf_counter(), {}
        t_log, step_log = t0, self.step
        try:
            while self.step < cfg.steps:
                batch = self.batch(self.step)
                losses = self.model(batch, step_seed(self.cfg.seed, self.step, self.rank))
                self.opt.zero_grad(set_to_none=True)
                losses["loss"].backward()
                if cfg.grad_clip > 0:
                    torch.nn.utils.clip_grad_norm_([p for p in self.stage.parameters() if p.requires_grad],
                                                   cfg.grad_clip)
                self.opt.step()
                self.sched.step()
                self.step += 1
                bar.update(1)
                if self.step % cfg.log_every == 0 or self.step == cfg.steps:
                    now = time.perf_counter()
                    rate = (self.step - step_log) / max(now - t_log, 1e-9)
                    t_log, step_log = now, self.step
                    last = {"step": self.step, **{k: float(v.detach()) for k, v in losses.items()},
                            "lr": self.sched.get_last_lr()[0], "it_per_s": round(rate, 3),
                            "seconds": round(now - t0, 2)}
                    self.history.append(last)
                    bar.set_postfix(loss=f"{last['loss']:.4f}")
                if self.step % cfg.checkpoint_every == 0:
                    self.save_checkpoint()
                if self._stop or (self.stop_after is not None and self.step >= self.stop_after):
                    self.save_checkpoint()
                    if self.rank == 0 and self._stop:
                        print(f"\nstopped at step {self.step}; checkpoint in {self.checkpoint_path} "
                              f"(continue with --resume)")
                    return last
            self.save_checkpoint()
            self.export()
            return last
        finally:
            bar.close()
            for s, h in old.items():
                signal.signal(s, h)


def train(cfg: Config, *, resume: bool = False, progress: bool = True) -> dict:
    """Run a configured stage to the end (or until a signal); returns the last logged losses."""
    trainer = Trainer(cfg, resume=resume, progress=progress)
    try:
        return trainer.run()
    finally:
        if trainer.world > 1 and dist.is_initialized():
            dist.destroy_process_group()


__all__ = ["Trainer", "train", "TrainingError", "step_seed"]
