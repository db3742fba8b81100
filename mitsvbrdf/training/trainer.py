"""The training driver: ``mitsvbrdf train CONFIG`` (also under ``torchrun``).

One loop for every stage: Adam with cosine annealing, seeded; a progress bar with the loss and
it/s; ``metrics.csv`` and ``loss.png``; checkpoints every ``train.checkpoint_every`` steps, on
SIGINT/SIGTERM (at the next step boundary) and at the end, written atomically; ``--resume``
continues exactly where the checkpoint left off (same batches, same render seeds, same optimiser
state, hence the same parameters as an uninterrupted run, bit for bit where the render is: Dr.Jit's
LLVM backend on several threads sums a render's gradient by atomic adds in thread order, so there
the two can differ in the last bit). At the end the stage's networks are
exported to ``OUT/networks.pt`` ({name: network record}, plus the acquisition settings under
``"acquisition"`` for stages whose networks acquire) for the next stage's ``[pretrained]``.

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
from dataclasses import replace
from pathlib import Path

import torch
import torch.distributed as dist

from ..acquisition import SETTINGS_KEY
from ..data.augment import crop_maps
from ..data.datasets import MapFolderDataset, ProceduralDataset, StripDataset, collate_svbrdf
from ..errors import MitsvbrdfError
from ..nets import network_record
from ..nets.io import read_network_file, write_network_file
from ..rig import DEFAULT_SCENE, Rig
from ..scene_xml import write_integrator_options
from ..sensor import SensorNoise
from ..svbrdf import SVBRDF
from .config import Config, config_table
from .loss_plot import write_loss_plot
from .stages import STAGES, RenderSettings, TrainingStage


class TrainingError(MitsvbrdfError):
    """A run that cannot start or continue (missing checkpoint, incompatible files)."""


class TrainingInterrupted(RuntimeError):
    """SIGINT or SIGTERM stopped the run at a step boundary, after its checkpoint was written.

    ``signal`` is the signal's number (the CLI exits with 128 + it), ``step`` the step reached."""

    def __init__(self, signum: int, step: int, checkpoint: Path):
        self.signal, self.step, self.checkpoint = signum, step, checkpoint
        super().__init__(f"stopped at step {step} by {signal.Signals(signum).name}; checkpoint in {checkpoint} "
                         "(continue with --resume)")


#: Files a run writes into its folder (besides config.json); ``--overwrite`` removes them first.
RUN_FILES = ("checkpoint.pt", "networks.pt", "metrics.csv", "loss.png")

#: Config keys that may differ when a run is resumed: where the run lives and how it is watched,
#: and train.steps, which may grow (not below the checkpoint's step). Anything else changes what
#: the earlier steps computed, so --resume refuses it.
RESUMABLE_CHANGES = ("out", "train.steps", "train.checkpoint_every", "train.log_every", "train.device",
                     "train.time_budget")


def _flatten(table: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in table.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def config_changes(old: dict, new: dict) -> list[str]:
    """Keys (dotted) whose values differ between two config tables, outside RESUMABLE_CHANGES."""
    a, b = _flatten(old), _flatten(new)
    return sorted(k for k in set(a) | set(b)
                  if k not in RESUMABLE_CHANGES and a.get(k, "<absent>") != b.get(k, "<absent>"))


def _plain(value, where: str = "checkpoint") -> None:
    """Raise TypeError unless ``value`` is made of tensors, numbers, strings, None and containers of
    them: what ``torch.load(..., weights_only=True)`` reads back without running code."""
    if isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, (str, int)):
                raise TypeError(f"{where}: key {k!r} is a {type(k).__name__}")
            _plain(v, f"{where}.{k}")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _plain(v, f"{where}[{i}]")
    elif not (value is None or isinstance(value, (torch.Tensor, bool, int, float, str))):
        raise TypeError(f"{where} is a {type(value).__name__}, not a tensor, number or string")


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise TrainingError("train.device = 'cuda' but no CUDA device is available")
    return torch.device(name)


def make_dataset(cfg: Config):
    d = cfg.data
    size = d.crop_from or d.size  # with windows, the materials they are cut from
    if d.source == "procedural":
        return ProceduralDataset(d.length, size, seed=cfg.seed, families=d.families or None, bump=tuple(d.bump),
                                 dark_metals=d.dark_metals)
    if d.source == "strips":
        return StripDataset(d.root, crop=size)
    return MapFolderDataset(d.root, crop=size)


def window_of_step(grid: int, size: int, seed: int) -> tuple[int, int]:
    """(top, left) of a step's size x size window of grid x grid materials (``data.crop_from``),
    uniform over the places it fits, drawn from the step's seed."""
    g = torch.Generator().manual_seed(seed)
    top, left = torch.randint(0, grid - size + 1, (2,), generator=g).tolist()
    return top, left


def step_seed(seed: int, step: int, rank: int) -> int:
    """Render/noise seed of a step on a rank (kept below 2^31 for every backend)."""
    return (seed * 1_000_003 + step * 101 + rank * 7919) % (2 ** 31 - 1)


class Trainer:
    """Runs one configured stage. ``rank``/``world`` come from torchrun's environment."""

    def __init__(self, cfg: Config, *, resume: bool = False, progress: bool = True, stop_after: int | None = None,
                 overwrite: bool = False):
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
        if resume and overwrite:
            raise TrainingError("--resume continues the run in the folder and --overwrite starts it again: choose one")
        existing = [f for f in RUN_FILES[:2] if (self.out / f).exists()]
        if existing and not resume and not overwrite:
            raise TrainingError(f"{self.out} already holds a run ({', '.join(existing)}): pass --resume to "
                                "continue it, --overwrite to start it again, or choose another out")
        self.progress = progress and self.rank == 0
        self.stop_after = stop_after  # tests: stop as if killed after this many steps
        torch.manual_seed(cfg.seed)
        rig = self._training_rig()
        noise = SensorNoise(**vars(cfg.render.noise))
        settings = RenderSettings(cfg.render.method, cfg.render.spp, noise if noise.active else None,
                                  cfg.render.ltc_mode)
        cls = STAGES[cfg.stage]
        self.rig = rig  # the stage's, unless data.crop_from gives each step a window of it
        self.stage: TrainingStage = cls(cfg.model, cfg.loss, settings, rig)
        if cls.PRETRAINED or cfg.pretrained.warm_start or cfg.pretrained.scratch:
            self._load_pretrained()
        self.stage.to(self.device)
        groups = [g for g in self.stage.param_groups(cfg.train.lr) if g["params"]]
        if not groups:
            raise TrainingError(f"stage {cfg.stage!r} has nothing to train")
        # foreach: one multi-tensor update instead of a Python loop over ~100 small parameters
        self.opt = torch.optim.Adam(groups, lr=cfg.train.lr, weight_decay=cfg.train.weight_decay, foreach=True)
        self.sched = torch.optim.lr_scheduler.CosineAnnealingLR(self.opt, cfg.train.steps, eta_min=cfg.train.lr_min)
        self.model = self.stage
        if self.world > 1:
            self.model = torch.nn.parallel.DistributedDataParallel(
                self.stage, device_ids=[self.device.index] if self.device.type == "cuda" else None,
                find_unused_parameters=True)
        self.dataset = make_dataset(cfg)
        self.step = 0
        self.elapsed = 0.0     # seconds spent in the loop, over all resumed runs
        self.finished = False  # the run reached train.steps or spent its time budget
        self.history: list[dict] = []
        self._stop = False
        self._signal: int | None = None
        if resume:
            self._load_checkpoint()
        if self.rank == 0:
            import json

            if overwrite:
                for f in RUN_FILES:
                    (self.out / f).unlink(missing_ok=True)
            self.out.mkdir(parents=True, exist_ok=True)
            (self.out / "config.json").write_text(json.dumps(config_table(cfg), indent=1, default=str))

    def _training_rig(self) -> Rig:
        """The config's rig; with ``render.integrator`` options, read from a copy of its scene file
        in the run folder with those options on the integrator, loaded now so that an unknown or
        bad option stops the run before its first step."""
        options = self.cfg.render.integrator
        if not options:
            return Rig.from_scene(self.cfg.scene or None)
        from ..render.mitsuba import load_scene, variant_for

        self.out.mkdir(parents=True, exist_ok=True)
        name = "scene.xml" if self.world == 1 else f"scene.rank{self.rank}.xml"  # no two writers of one file
        path = write_integrator_options(self.cfg.scene or DEFAULT_SCENE, self.out / name, **options)
        load_scene(str(path), variant_for(self.device))
        return Rig.from_scene(path)

    # -- files ------------------------------------------------------------------------------
    @property
    def checkpoint_path(self) -> Path:
        return self.out / "checkpoint.pt"

    def _load_pretrained(self) -> None:
        pre = self.cfg.pretrained
        if self.stage.PRETRAINED:
            path = Path(pre.networks)
            if not pre.networks or not path.exists():
                raise TrainingError(f"stage {self.cfg.stage!r} starts from an earlier stage's networks: set "
                                    f"pretrained.networks (now {str(path)!r}, which does not exist)")
            self.stage.load_pretrained(read_network_file(path, "networks"))
        if pre.scratch:
            trained = sorted(n for n in self.stage.nets if n not in self.stage.PRETRAINED)
            if not pre.warm_start or not set(pre.scratch) <= set(trained):
                raise TrainingError(f"pretrained.scratch {pre.scratch} must name networks stage {self.cfg.stage!r} "
                                    f"trains ({trained}) and go with a pretrained.warm_start")
        if pre.warm_start:
            path = Path(pre.warm_start)
            if not path.exists():
                raise TrainingError(f"pretrained.warm_start: {str(path)!r} does not exist")
            records = read_network_file(path, "networks")
            self.stage.warm_start({k: v for k, v in records.items() if k not in pre.scratch})

    def _load_checkpoint(self) -> None:
        path = self.checkpoint_path
        if not path.exists():
            raise TrainingError(f"--resume: no checkpoint at {path}")
        try:
            # weights_only: a checkpoint is data (tensors, numbers, strings); one from elsewhere
            # cannot run code when it is read.
            ck = torch.load(path, map_location=self.device, weights_only=True)
        except Exception as e:  # truncated, corrupt, or pickled objects that are not plain data
            raise TrainingError(f"--resume: {path} cannot be read as a checkpoint ({_first_line(e)}); "
                                "restore it, or start again with --overwrite") from None
        needed = ("stage", "optimizer", "scheduler", "rng", "step", "history", "config")
        if not isinstance(ck, dict) or any(k not in ck for k in needed) or not isinstance(ck["config"], dict):
            raise TrainingError(f"--resume: {path} is not a training checkpoint of this version")
        if ck["config"].get("stage") != self.cfg.stage:
            raise TrainingError(f"--resume: {path} is a {ck['config'].get('stage')!r} run, "
                                f"the config trains {self.cfg.stage!r}")
        new = config_table(self.cfg)
        changed = config_changes(ck["config"], new)
        if changed:
            old, now = _flatten(ck["config"]), _flatten(new)
            shown = "; ".join(f"{k} = {old.get(k, '<absent>')!r} then, {now.get(k, '<absent>')!r} now"
                              for k in changed[:4])
            more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
            raise TrainingError(f"--resume: the settings differ from the checkpoint's: {shown}{more} (only "
                                f"{', '.join(RESUMABLE_CHANGES)} may change; start a new run for the rest)")
        if self.cfg.train.steps < ck["step"]:
            raise TrainingError(f"--resume: train.steps = {self.cfg.train.steps} but {path} is at step {ck['step']}")
        try:
            self.stage.load_state_dict(ck["stage"])
            self.opt.load_state_dict(ck["optimizer"])
            self.sched.load_state_dict(ck["scheduler"])
        except (RuntimeError, ValueError, KeyError) as e:
            # load_state_dict lists every mismatching tensor on its own line: name the first
            lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
            detail = lines[1] if len(lines) > 1 else _first_line(e)
            more = f" and {len(lines) - 2} more" if len(lines) > 2 else ""
            raise TrainingError(f"--resume: {path} does not fit these networks ({detail}{more})") from None
        # More steps than the checkpoint's run planned: the cosine schedule continues from the
        # current rate and ends at lr_min on the new last step.
        self.sched.T_max = self.cfg.train.steps
        torch.set_rng_state(ck["rng"].cpu())
        self.step = ck["step"]
        self.history = ck["history"]
        self.elapsed = float(ck.get("elapsed", 0.0))
        self.finished = bool(ck.get("finished", False))

    def save_checkpoint(self) -> None:
        if self.rank != 0:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        ck = {"stage": self.stage.state_dict(), "optimizer": self.opt.state_dict(),
              "scheduler": self.sched.state_dict(), "rng": torch.get_rng_state(), "step": self.step,
              "history": self.history, "config": config_table(self.cfg), "elapsed": self.elapsed,
              "finished": self.finished}
        _plain(ck)  # what _load_checkpoint reads with weights_only=True
        tmp = self.checkpoint_path.with_suffix(".tmp")
        torch.save(ck, tmp)
        os.replace(tmp, self.checkpoint_path)
        self._write_metrics()

    def export(self) -> Path:
        path = self.out / "networks.pt"
        if self.rank == 0:
            recs = {n: network_record(net) for n, net in self.stage.networks().items()}
            settings = self.stage.acquisition_settings()
            if settings is not None:  # how an acquisition must use them (L_pdf source and stride, I^spec,
                # the texel grid they trained on)
                # the texel grid the networks learned: with windows, that of the materials they were cut from
                recs[SETTINGS_KEY] = replace(settings, resolution=self.cfg.data.crop_from or self.cfg.data.size).record()
            write_network_file(path, recs)
        return path

    def _write_metrics(self) -> None:
        if not self.history:
            return
        keys = list(dict.fromkeys(k for h in self.history for k in h))
        with open(self.out / "metrics.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            w.writerows(self.history)
        write_loss_plot(self.history, self.out / "loss.png", f"{self.cfg.stage}: {self.cfg.out}")

    # -- the loop ---------------------------------------------------------------------------
    def batch(self, step: int):
        """This rank's share of the materials of ``step`` (on the device). With ``data.crop_from``
        it is the step's window of them, and the stage renders with that window's rig."""
        b = self.cfg.train.batch // self.world
        start = step * self.cfg.train.batch + self.rank * b
        n = len(self.dataset)
        idx = [(start + i) % n for i in range(b)]
        fetch = getattr(self.dataset, "__getitems__", None)
        items = fetch(idx) if fetch else [self.dataset[i] for i in idx]
        batch = collate_svbrdf(items)
        d = self.cfg.data
        if d.crop_from:
            top, left = window_of_step(d.crop_from, d.size, step_seed(self.cfg.seed, step, self.rank))
            batch = SVBRDF(**crop_maps(batch.maps(), top, left, d.size))
            self.stage.rig = self.rig.window(d.crop_from, top, left, d.size)
        return batch.to(self.device)

    def budget_spent(self) -> bool:
        budget = self.cfg.train.time_budget
        return budget > 0 and self.elapsed >= budget

    def _budget_lr(self) -> None:
        """The cosine schedule on the elapsed fraction of the time budget (module docstring)."""
        cfg = self.cfg.train
        f = min(self.elapsed / cfg.time_budget, 1.0)
        for group, base in zip(self.opt.param_groups, self.sched.base_lrs):
            group["lr"] = cfg.lr_min + (base - cfg.lr_min) * 0.5 * (1.0 + math.cos(math.pi * f))

    def _handle(self, signum, frame) -> None:
        if self._stop:  # a second signal: stop now, without the checkpoint of the step in flight
            raise KeyboardInterrupt
        self._stop, self._signal = True, signum

    def run(self) -> dict:
        """Train to ``train.steps``; returns the last logged losses."""
        from tqdm import tqdm

        cfg = self.cfg.train
        old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
        # a budgeted run's bar counts seconds of its budget (its steps are only an upper bound)
        budgeted = cfg.time_budget > 0
        bar = tqdm(total=math.ceil(cfg.time_budget) if budgeted else cfg.steps,
                   initial=int(min(self.elapsed, cfg.time_budget)) if budgeted else self.step,
                   unit="s" if budgeted else "it", desc=self.cfg.stage, disable=not self.progress)
        t0, last = time.perf_counter(), {}
        t_log, step_log = t0, self.step
        elapsed0 = self.elapsed
        try:
            while self.step < cfg.steps and not self.budget_spent():
                if cfg.time_budget > 0:
                    self._budget_lr()
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
                now = time.perf_counter()
                self.elapsed = elapsed0 + (now - t0)
                bar.update(int(min(self.elapsed, cfg.time_budget)) - bar.n if budgeted else 1)  # whole seconds
                if self.step % cfg.log_every == 0 or self.step == cfg.steps or self.budget_spent():
                    rate = (self.step - step_log) / max(now - t_log, 1e-9)
                    t_log, step_log = now, self.step
                    last = {"step": self.step, **{k: float(v.detach()) for k, v in losses.items()},
                            "lr": self.opt.param_groups[0]["lr"], "it_per_s": round(rate, 3),
                            "seconds": round(self.elapsed, 2)}
                    self.history.append(last)
                    bar.set_postfix(**({"step": self.step} if budgeted else {}), loss=f"{last['loss']:.4f}")
                if self.step % cfg.checkpoint_every == 0:
                    self.save_checkpoint()
                if self._stop or (self.stop_after is not None and self.step >= self.stop_after):
                    self.save_checkpoint()
                    if self._stop:
                        self.export()
                        raise TrainingInterrupted(self._signal, self.step, self.checkpoint_path)
                    return last
            self.finished = True
            self.save_checkpoint()
            self.export()
            return last
        finally:
            bar.close()
            for s, h in old.items():
                signal.signal(s, h)


def train(cfg: Config, *, resume: bool = False, progress: bool = True, overwrite: bool = False) -> dict:
    """Run a configured stage to the end; returns the last logged losses. Raises
    :class:`TrainingInterrupted` after checkpointing when SIGINT or SIGTERM stops it."""
    trainer = Trainer(cfg, resume=resume, progress=progress, overwrite=overwrite)
    try:
        return trainer.run()
    finally:
        if trainer.world > 1 and dist.is_initialized():
            dist.destroy_process_group()


__all__ = ["Trainer", "train", "TrainingError", "TrainingInterrupted", "step_seed", "RESUMABLE_CHANGES", "RUN_FILES"]
