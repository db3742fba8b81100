#!/usr/bin/env python
"""How much a G_sc learns per step: learning rate, map-loss weights and clipping at equal steps.

The from-scratch chains of issue 15 end undertrained: their fine-tuning loss still falls at the end
of the 150-minute bound, and their 256 px averages miss the goals through the maps G_sc predicts
(docs/evaluation/chain-scratch-gsc/). A setting that makes each step worth more moves them
without a faster step. This study trains the same G_sc from scratch several times, each *arm* with
other training settings and everything else equal (seed, data stream, initial weights, steps),
and scores the exports on the same held-out materials and captures.

The G_sc is that of the shipped recipe (width 16 with the diffuse-ratio inputs; 64 px materials
with their relief and dark metals, 4-spp Mitsuba captures, the normal map weighted 5x:
``table3.SHIPPED_RECIPE``) behind fixed MonoGrad patterns (``train/fixed-monograd-small.toml``),
so no G_l, L_pdf or pattern prediction enters: what differs between arms is G_sc's learning alone.
A chain's G_sc (stage 2, fine-tuning) also reads I^spec and learns behind predicted patterns, so a
ranking here is a candidate for a chain, not a chain's result.

Arms (:data:`ARMS`, ``--arms`` picks some): the default learning rate 1e-3 (``lr1e-3``, the
reference every other arm is paired with), 5e-4, 2e-3 and 4e-3 under the same cosine schedule to
0; at 1e-3, the roughness map weighted 3x in the map loss (``rough3``: roughness is the largest map
error of every from-scratch export), the paper's plain L1 (``plain``: every map weighted 1, where
the recipe weights the normals 5x) and no gradient clipping (``noclip``; the default clips the
gradient's norm at 1). Runs go to ``runs/gsc-sample-efficiency/<arm>`` (kept when
their ``networks.pt`` is there; resumed from a checkpoint), ``--jobs`` of them at once; with equal
steps the arms' results do not depend on how they shared the cores, only their wall times do.

Scores: ``mitsvbrdf evaluate`` at 64 px and at 256 px (the default "fused" transfer) on ``--n``
held-out procedural materials at 32 spp, each arm a ``--baseline`` beside the shipped networks
(the required ``--model``, a row for scale). Printed and written to
``docs/benchmarks/gsc_sample_efficiency[_<name>].{md,csv}``: every arm's map RMSE, its paired difference
from the reference arm (mean +- standard error over the materials), and a figure of the running
mean of each arm's training loss (the ``.png`` of the same name; an arm with other map weights
has its loss on another scale there, while the scores are unweighted RMSE).

    python benchmarks/gsc_sample_efficiency.py [--steps 6000] [--jobs 4] [--n 32] [--arms lr1e-3,lr2e-3] [--name NAME]
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import time
from pathlib import Path

from mitsvbrdf.evaluation import MAP_COLUMNS as MAPS, paired_difference
from mitsvbrdf.training.loss_plot import running_mean, smoothing_window
from report import write_report
from run_queue import ROOT, Run, train_all
from table3 import SHIPPED_RECIPE

CONFIG = ROOT / "train" / "fixed-monograd-small.toml"
REFERENCE = "lr1e-3"
#: arm name -> its ``--set`` overrides, on top of the shipped recipe's G_sc settings
ARMS = {"lr1e-3": ["train.lr=1e-3"],
        "lr2e-3": ["train.lr=2e-3"],
        "lr4e-3": ["train.lr=4e-3"],
        "lr5e-4": ["train.lr=5e-4"],
        "rough3": ["train.lr=1e-3", "loss.map_weights=[5.0, 1.0, 3.0, 1.0]"],
        "plain": ["train.lr=1e-3", "loss.map_weights=[1.0, 1.0, 1.0, 1.0]"],
        "noclip": ["train.lr=1e-3", "train.grad_clip=0"]}
SIZES = (64, 256)


def plan(arms: list[str], steps: int, runs_dir: Path) -> dict[str, Run]:
    """One run of :data:`CONFIG` per arm: the shipped recipe's data, loss and G_sc, ``steps`` steps."""
    common = [*SHIPPED_RECIPE["*"], *SHIPPED_RECIPE["fixed"], f"train.steps={steps}", f"train.checkpoint_every={min(500, steps)}"]
    return {a: Run(a, CONFIG, runs_dir / a, None, [*common, *ARMS[a], f'out="{runs_dir / a}"']) for a in arms}


def evaluate(runs: dict[str, Run], size: int, n: int, spp: int, out: Path) -> list[dict]:
    """Score every arm's export with ``mitsvbrdf evaluate`` at ``size`` px; the rows of its metrics.csv."""
    cmd = [sys.executable, "-m", "mitsvbrdf", "evaluate", "--model", str(ROOT / "mitsvbrdf" / "weights" / "networks.pt"),
           "--data", "procedural", "--n", str(n), "--size", str(size), "--spp", str(spp), "--figures", "0",
           "--out", str(out), "--quiet"]
    for a, r in runs.items():
        cmd += ["--baseline", f"{a}={r.out / 'networks.pt'}"]
    print(f"[gsc_sample_efficiency] {' '.join(cmd[1:])}", flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True)
    with open(out / "metrics.csv") as f:
        return list(csv.DictReader(f))


def metrics(run: Run) -> list[dict]:
    """The rows of a finished run's metrics.csv (step, loss terms, lr, seconds of training)."""
    with open(run.out / "metrics.csv") as f:
        return list(csv.DictReader(f))


def loss_figure(histories: dict[str, list[dict]], path: Path) -> None:
    """The running mean of each arm's logged reconstruction loss against its step, one line per arm."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for a, rows in histories.items():
        steps = [int(row["step"]) for row in rows]
        loss = [float(row["reconstruction"]) for row in rows]
        ax.plot(steps, running_mean(loss, smoothing_window(len(loss))), label=a)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("weighted map loss (running mean)")
    ax.set_title("G_sc from scratch behind MonoGrad, per arm")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--arms", default=",".join(ARMS), help=f"comma-separated arms of {list(ARMS)}")
    ap.add_argument("--steps", type=int, default=6000, help="steps of every arm (default 6000)")
    ap.add_argument("--jobs", type=int, default=4, help="arms trained at once (default 4)")
    ap.add_argument("--n", type=int, default=32, help="held-out procedural materials scored (default 32)")
    ap.add_argument("--spp", type=int, default=32, help="samples per pixel of the scored captures (default 32)")
    ap.add_argument("--runs", default=str(ROOT / "runs" / "gsc-sample-efficiency"), help="folder of the arms' runs")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks"))
    ap.add_argument("--name", default="", help="suffix of the report's files (gsc_sample_efficiency_<name>.md)")
    args = ap.parse_args()
    arms = [a for a in args.arms.split(",") if a]
    unknown = [a for a in arms if a not in ARMS]
    if unknown or REFERENCE not in arms:
        ap.error(f"--arms must name arms of {list(ARMS)} and include {REFERENCE!r}; got {arms}")
    if args.steps < 1 or args.jobs < 1 or args.n < 2 or args.spp < 1:
        ap.error("--steps, --jobs and --spp must be positive and --n at least 2")
    runs = plan(arms, args.steps, Path(args.runs))
    t0 = time.perf_counter()
    train_all(runs, sys.executable, args.jobs, tag="gsc_sample_efficiency")
    print(f"[gsc_sample_efficiency] training: {time.perf_counter() - t0:.0f} s", flush=True)

    out = Path(args.out)
    stem = "gsc_sample_efficiency" + (f"_{args.name}" if args.name else "")
    table, csv_rows = [], []
    for size in SIZES:
        rows = evaluate(runs, size, args.n, args.spp, Path(args.runs) / f"eval-{size}")
        for a in arms:
            mine = [r for r in rows if r["method"] == a]
            means = {m: sum(float(r[m]) for r in mine) / len(mine) for m in MAPS}
            diffs = {m: paired_difference(rows, REFERENCE, a, key=m) for m in MAPS} if a != REFERENCE else {}
            csv_rows.append({"px": size, "arm": a, **{m: round(means[m], 5) for m in MAPS},
                             **{f"{m}_vs_ref": round(diffs[m].mean, 5) if diffs else 0.0 for m in MAPS},
                             **{f"{m}_vs_ref_se": round(diffs[m].se, 5) if diffs else 0.0 for m in MAPS}})
            cells = [f"{means[m]:.4f}" + (f" ({diffs[m]})" if diffs else "") for m in MAPS]
            lower = f"{len(mine) - diffs['rmse_average'].a_lower}/{len(mine)}" if diffs else ""
            table.append(f"| {size} | {a} | " + " | ".join(cells) + f" | {lower} |")
    out.mkdir(parents=True, exist_ok=True)
    histories = {a: metrics(r) for a, r in runs.items()}
    loss_figure(histories, out / f"{stem}.png")
    reweighted = [a for a in arms if any(o.startswith("loss.map_weights") for o in ARMS[a])]
    arms_text = "; ".join(f"`{a}`: {', '.join(f'`{o}`' for o in ARMS[a])}" for a in arms)
    text = (f"Command: `benchmarks/gsc_sample_efficiency.py --steps {args.steps} --n {args.n} --spp {args.spp} "
            f"--arms {','.join(arms)}" + (f" --name {args.name}" if args.name else "") + "`\n\n"
            f"G_sc of the shipped recipe trained from scratch behind fixed MonoGrad patterns, {args.steps} steps of "
            f"batch 4 per arm, same seed and data (the module docstring says why and what this does not show). "
            f"Every arm with `{CONFIG.relative_to(ROOT)}` and "
            + ", ".join(f"`{o}`" for o in [*SHIPPED_RECIPE["*"], *SHIPPED_RECIPE["fixed"]]) + f"; the arms: {arms_text}.\n\n"
            f"Map RMSE (encoded maps) over {args.n} held-out procedural materials, captures at {args.spp} spp; "
            f"in brackets each arm minus `{REFERENCE}`, mean +- standard error over the materials (negative: "
            f"better), and on how many materials the arm's average is lower than `{REFERENCE}`'s.\n\n"
            "| px | arm | normal | diffuse | roughness | specular | average | lower |\n"
            "|---:|---|---:|---:|---:|---:|---:|---:|\n" + "\n".join(table) + "\n\n"
            "Seconds of training per arm (with the arms side by side, sharing the cores): "
            + ", ".join(f"{a} {float(h[-1]['seconds']):.0f}" for a, h in histories.items()) + ".\n\n"
            "Running mean of each arm's training loss (the weighted map loss" + (
                f"; {' and '.join(f'`{a}`' for a in reweighted)}: other map weights, so another scale"
                if reweighted else "") + f"):\n\n![loss]({stem}.png)\n")
    write_report(out, stem, "G_sc sample efficiency: learning rate, map weights and clipping at equal steps",
                 "gsc_sample_efficiency.py", text, csv_rows)
    print(text)


if __name__ == "__main__":
    main()
