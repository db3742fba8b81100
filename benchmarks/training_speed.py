"""Training throughput per stage and resolution, and where a step's time goes.

    .venv/bin/python benchmarks/training_speed.py                          # this CPU, 64/128/256 px
    python3 benchmarks/training_speed.py --device cuda --sizes 256 --batch 8   # a GPU

Each stage of the shipped chain (train/chains/small.toml: its stage configs with the chain's
overrides, i.e. what ``mitsvbrdf train-chain`` trains) runs ``--steps`` timed steps after
``--warmup`` untimed ones (kernel compilation, caches) at every size of ``--sizes``. A step is
split into:

* ``data``: drawing the batch from the procedural stream;
* ``L_pdf``: the importance map of the initializer's estimate (stages 1, 2 and fine-tuning);
* ``render``: the forward renders of the captures (I_0 and the adaptive ones);
* ``nets fwd``: the rest of the forward pass: the networks and the losses;
* ``backward``: autograd through the networks (and, in stages 1-2, through the renderer to G_l);
* ``optimizer``: gradient clipping and the Adam update.

The parts are timed by wrapping the stage's ``capture`` and the L_pdf function the acquisition
layer's ``predict`` calls (``mitsvbrdf.acquisition.importance``) for the duration of
the measurement, so they are what training runs. Each stage starts from the previous stage's
networks after these few steps (the speed does not depend on the weights). Writes
docs/benchmarks/training_speed_<device>.md (+ CSV), or training_speed_<device>_<chain>.md for a
``--chain`` other than small.toml, with ``_<name>`` appended for ``--name`` (a variant's
``--set`` overrides, e.g. ``--set data.crop_from=256 --name windows``: every step a 64 px window
of 256 px materials). The ``data`` part of a windowed step includes making the 256 px materials.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch

from mitsvbrdf import acquisition
from mitsvbrdf.training import Trainer, load_config
from mitsvbrdf.training.chain import load_chain
from mitsvbrdf.training.trainer import step_seed
from report import write_report

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("data", "L_pdf", "render", "nets fwd", "backward", "optimizer")


class PartTimer:
    """Accumulates wall time per part; ``sync`` makes GPU timings honest."""

    def __init__(self, device: torch.device):
        self.device, self.seconds, self.restore = device, defaultdict(float), []

    def sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize()

    def wrap(self, obj, name: str, part: str) -> None:
        inner = getattr(obj, name)

        def timed(*a, **k):
            self.sync()
            t = time.perf_counter()
            out = inner(*a, **k)
            self.sync()
            self.seconds[part] += time.perf_counter() - t
            return out

        setattr(obj, name, timed)
        self.restore.append((obj, name, inner))

    def unwrap(self) -> None:
        for obj, name, inner in reversed(self.restore):
            setattr(obj, name, inner)
        self.restore.clear()


def timed_steps(trainer: Trainer, steps: int, start: int) -> dict[str, float]:
    """Seconds per part over ``steps`` training steps (the trainer's own step, taken apart)."""
    timer = PartTimer(trainer.device)
    stage = trainer.stage
    timer.wrap(stage, "capture", "render")
    timer.wrap(acquisition, "importance", "L_pdf")  # what acquisition.predict calls for L_pdf
    clip = trainer.cfg.train.grad_clip
    total_fwd = 0.0
    for step in range(start, start + steps):
        timer.sync()
        t0 = time.perf_counter()
        batch = trainer.batch(step)
        timer.sync()
        t1 = time.perf_counter()
        losses = trainer.model(batch, step_seed(trainer.cfg.seed, step, 0))
        timer.sync()
        t2 = time.perf_counter()
        trainer.opt.zero_grad(set_to_none=True)
        losses["loss"].backward()
        timer.sync()
        t3 = time.perf_counter()
        if clip > 0:
            torch.nn.utils.clip_grad_norm_([p for p in stage.parameters() if p.requires_grad], clip)
        trainer.opt.step()
        timer.sync()
        t4 = time.perf_counter()
        timer.seconds["data"] += t1 - t0
        total_fwd += t2 - t1
        timer.seconds["backward"] += t3 - t2
        timer.seconds["optimizer"] += t4 - t3
    timer.unwrap()
    timer.seconds["nets fwd"] = total_fwd - timer.seconds["render"] - timer.seconds["L_pdf"]
    return {p: timer.seconds[p] / steps for p in PARTS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--chain", type=Path, default=ROOT / "train" / "chains" / "small.toml")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--sizes", default="64,128,256")
    ap.add_argument("--batch", type=int, default=0, help="batch size (0: the configs')")
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a config override for every stage after the chain's (repeatable), e.g. data.crop_from=256")
    ap.add_argument("--name", default="", help="suffix of the output files (e.g. 'windows' for a --set variant)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    chain = load_chain(args.chain, time_budget=1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for size in (int(s) for s in args.sizes.split(",")):
            previous = None
            for st in chain.stages:
                sets = [*chain.overrides, *st.overrides, f"data.size={size}", f"train.device={args.device}",
                        f'out="{tmp / str(size) / st.config.stem}"', "train.checkpoint_every=1000000000",
                        f"train.steps={args.warmup + args.steps + 1}", *args.set]
                if args.batch:
                    sets.append(f"train.batch={args.batch}")
                cfg = load_config(st.config, sets)
                if previous is not None:
                    cfg.pretrained.networks = str(previous)
                trainer = Trainer(cfg, progress=False)
                timed_steps(trainer, args.warmup, 0)
                parts = timed_steps(trainer, args.steps, args.warmup)
                total = sum(parts.values())
                row = {"stage": cfg.stage, "px": size, "batch": cfg.train.batch, "render": cfg.render.method,
                       "spp": cfg.render.spp, "s_per_step": round(total, 4), "it_per_s": round(1 / total, 3),
                       **{f"{p} %": round(100 * parts[p] / total, 1) for p in PARTS}}
                rows.append(row)
                print(row, flush=True)
                previous = trainer.export()  # the next stage starts from these (barely trained) networks
    dev = args.device if args.device == "cpu" else torch.cuda.get_device_name()
    head = "| stage | px | batch | s/step | it/s | " + " | ".join(PARTS) + " |\n|---|---:|---:|---:|---:|" + \
        "---:|" * len(PARTS) + "\n"
    body = "\n".join(f"| {r['stage']} | {r['px']} | {r['batch']} | {r['s_per_step']} | {r['it_per_s']} | " +
                     " | ".join(f"{r[f'{p} %']}" for p in PARTS) + " |" for r in rows)
    text = (f"Command: `{' '.join(['benchmarks/training_speed.py', *[a for a in __import__('sys').argv[1:]]])}`\n\n"
            f"The stages of `{args.chain.relative_to(ROOT) if args.chain.is_relative_to(ROOT) else args.chain}` "
            + (f"with {', '.join(f'`{o}`' for o in args.set)} " if args.set else "") +
            f"on {dev} ({torch.get_num_threads()} threads), {cfg.render.method} captures at {cfg.render.spp} spp; "
            f"mean of {args.steps} steps after {args.warmup} warm-up step(s). Share of a step in % per part "
            "(benchmarks/training_speed.py's docstring defines them).\n\n" + head + body + "\n")
    print(text)
    # the shipped chain's table keeps its name; another chain's gets the chain's name appended
    stem = f"training_speed_{args.device}" + ("" if args.chain.name == "small.toml" else f"_{args.chain.stem}") + \
        (f"_{args.name}" if args.name else "")
    write_report(args.out, stem, "Training throughput", "training_speed.py", text, rows)


if __name__ == "__main__":
    main()
