"""Which renderer should G_sc learn from? The same G_sc trained on captures from each renderer,
scored on the same held-out materials rendered by the reference renderer.

    .venv/bin/python benchmarks/training_renderer.py                 # trains, scores, writes docs/benchmarks/training_renderer.*
    .venv/bin/python benchmarks/training_renderer.py --eval-only     # re-score finished runs
    .venv/bin/python benchmarks/training_renderer.py --quick         # smoke run (tiny), nothing written

Every run is ``train/fixed-monograd-small.toml`` (the MonoGrad baseline: G_sc with fixed
patterns) at ``--size`` px, width ``--width``, ``--steps`` steps, batch 4, seed 4 (same data
stream, same initialisation; see ``--seeds``); only the renderer of the training captures differs:

* ``mitsuba-plain``: the ``importance`` integrator as it was (independent samples, no control
  variate), 4 spp;
* ``mitsuba-cv``: stratified samples with the diffuse + LTC control variate under one radiance
  per texel (``control_variate = "ltc"``, the default before ``ltc-cells``), 4 spp;
* ``mitsuba-cells``: stratified samples, both lobes known in closed form under every LCD cell's
  radiance (``ltc-cells``, the default before ``ltc-grid``), 4 spp;
* ``mitsuba-grid``: the default integrator (stratified samples, the lobes known in closed form
  under a 4 x 4 grid of cell blocks and an 8 x 8 window of cells around a narrow lobe's peak:
  ``ltc-grid``), 4 spp;
* ``ltc-prefiltered``: the paper's training renderer (noise-free, biased);
* ``reference``: the deterministic quadrature (clean and unbiased; the slowest), unless
  ``--skip-reference`` (then only its cost per step is probed).

With ``--seeds``, every run is trained once per seed (initialisation and data stream change
together) and the table gives means over seeds and materials plus paired differences against the
default integrator (``mitsuba-grid``) with their standard errors, so that run-to-run noise can
be told from an effect.

Each run is scored on ``--eval-n`` held-out procedural materials (seeds >= 1_000_000, never seen
in training) whose MonoGrad captures come from the reference renderer: map RMSE on encoded maps
per map and average, as ``mitsvbrdf evaluate`` reports it. The table also gives each run's seconds
per training step, measured for every run the same way (:func:`probe_seconds_per_step`: two short
probe runs of 5 and 20 steps after a warm-up run, the difference of their training clocks).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

from mitsvbrdf.scene_xml import write_integrator_options
from mitsvbrdf.evaluation import paired
from mitsvbrdf.rig import DEFAULT_SCENE

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "train" / "fixed-monograd-small.toml"
MAPS = ("normal", "diffuse", "roughness", "specular")

#: name -> (overrides of the config, integrator options written into a copy of the scene file or None)
#: The run that trains through the scene file's default integrator (the paired differences' base).
DEFAULT_RUN = "mitsuba-grid"
RUNS = {
    "mitsuba-plain": (["render.method=\"mitsuba\"", "render.spp=4"],
                      {"sampler": "independent", "control_variate": "none"}),
    "mitsuba-cv": (["render.method=\"mitsuba\"", "render.spp=4"], {"control_variate": "ltc"}),
    "mitsuba-cells": (["render.method=\"mitsuba\"", "render.spp=4"],
                      {"control_variate": "ltc-cells", "ltc_grid": 16, "ltc_cells_min_roughness": 0.2,
                       "ltc_window": 8, "ltc_window_min_roughness": 0.02}),
    "mitsuba-grid": (["render.method=\"mitsuba\"", "render.spp=4"], None),
    "ltc-prefiltered": (["render.method=\"ltc\"", "render.ltc_mode=\"prefiltered\""], None),
    "reference": (["render.method=\"reference\""], None),
}


def train(name: str, out: Path, args, runs: dict = RUNS) -> float:
    """Train run ``name`` of ``runs`` into ``out`` (resuming an interrupted run); returns its wall seconds."""
    overrides, options = runs[name]
    sets = [f"out=\"{out}\"", f"data.size={args.size}", f"model.svbrdf_width={args.width}",
            f"train.steps={args.steps}", "train.batch=4", f"seed={getattr(args, 'seed', 4)}",
            f"train.checkpoint_every={min(100, args.steps)}", f"train.log_every={min(10, args.steps)}", *overrides]
    if options is not None:
        scene = write_integrator_options(DEFAULT_SCENE, out.parent / f"{name}.xml", **options)
        sets.append(f"scene=\"{scene}\"")
    cmd = [sys.executable, "-m", "mitsvbrdf", "train", str(CONFIG)]
    if (out / "checkpoint.pt").exists():
        cmd.append("--resume")
    for s in sets:
        cmd += ["--set", s]
    print("+", " ".join(cmd), flush=True)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT)
    return time.perf_counter() - t0


def probe_seconds_per_step(name: str, args, runs: dict = RUNS) -> float:
    """Seconds per step of run ``name`` without training it: two short runs (5 and 20 steps) in a
    scratch folder, after a warm-up run that fills the kernel caches; the difference of the
    training loop's own clocks (metrics.csv ``seconds``, start-up excluded) over the 15 extra steps."""
    import csv
    import shutil
    from argparse import Namespace

    clocks = []
    for steps in (2, 5, 20):
        out = args.work / f"{name}-probe-{steps}"
        shutil.rmtree(out, ignore_errors=True)
        train(name, out, Namespace(**{**vars(args), "steps": steps}), runs)
        clocks.append(float(list(csv.DictReader((out / "metrics.csv").open()))[-1]["seconds"]))
        shutil.rmtree(out, ignore_errors=True)
    return (clocks[2] - clocks[1]) / 15


def score(networks: Path, materials, rig) -> dict[str, list[float]]:
    """Map RMSE (encoded maps) per map and their average, per material of ``materials``: each
    captured under the run's patterns by the reference renderer (clean and unbiased), reconstructed
    by its G_sc. {"rmse_normal": [...], ..., "rmse_average": [...]}."""
    from mitsvbrdf.acquisition import load_baseline
    from mitsvbrdf.metrics import map_rmse

    baseline = load_baseline(networks, rig)
    out: dict[str, list[float]] = {f"rmse_{k}": [] for k in (*MAPS, "average")}
    with torch.no_grad():
        for gt in materials:
            pred = baseline.simulate(gt, method="reference").svbrdf
            for k, v in map_rmse(pred, gt).items():
                out[f"rmse_{k}"].append(float(v[0]))
    return out


def score_rows(scores: dict[str, dict[str, list[float]]], probed: dict[str, float]) -> list[dict]:
    """One row per run: its seconds per step (when probed) and the mean of each score."""
    rows = []
    for name, sc in scores.items():
        row = {"run": name, "seconds_per_step": round(probed[name], 3) if name in probed else ""}
        row.update({k: round(sum(v) / len(v), 5) for k, v in sc.items()})
        rows.append(row)
        print(row, flush=True)
    return rows


def table_lines(rows: list[dict], keys: list[str], first: str = "run") -> list[str]:
    return ([f"| {first} | s / step | " + " | ".join(k.replace("rmse_", "") for k in keys) + " |",
             "|---|---:|" + "---:|" * len(keys)] +
            [f"| {r['run']} | {r['seconds_per_step']} | " + " | ".join(f"{r[k]:.4f}" for k in keys) + " |"
             for r in rows])


def paired_lines(scores: dict[str, dict[str, list[float]]], base: str, keys: list[str]) -> list[str]:
    """Table rows of each run's paired difference against ``base`` over the same (seed, material)
    pairs: mean +- standard error per score."""
    lines = ["| run | " + " | ".join(k.replace("rmse_", "") for k in keys) + " |", "|---|" + "---:|" * len(keys)]
    for name, sc in scores.items():
        if name == base:
            continue
        lines.append(f"| {name} | " + " | ".join(str(paired(scores[base][k], sc[k])) for k in keys) + " |")
    return lines


def study_parser(doc: str, runs: dict, steps: int, work: str) -> argparse.ArgumentParser:
    """The options every G_sc training study shares (this one and benchmarks/svbrdf_inputs.py)."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--steps", type=int, default=steps)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--width", type=int, default=16)
    ap.add_argument("--eval-n", type=int, default=16)
    ap.add_argument("--runs", default=",".join(runs), help="comma-separated subset of " + ", ".join(runs))
    ap.add_argument("--no-probe", action="store_true", help="leave out the seconds-per-step probes")
    ap.add_argument("--eval-only", action="store_true")
    ap.add_argument("--quick", action="store_true", help="3 steps at 16 px, 2 materials; nothing written")
    ap.add_argument("--work", type=Path, default=ROOT / "runs" / work)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    return ap


def study_runs(ap: argparse.ArgumentParser, args, runs: dict) -> list[str]:
    """The runs ``--runs`` names (an error for unknown ones); ``--quick`` shrinks everything."""
    names = [n for n in args.runs.split(",") if n]
    unknown = [n for n in names if n not in runs]
    if unknown:
        ap.error(f"unknown runs {unknown}; available: {', '.join(runs)}")
    if args.quick:
        args.steps, args.size, args.width, args.eval_n = 3, 16, 4, 2
        args.work = args.work.parent / (args.work.name + "-quick")
    return names


def main() -> None:
    ap = study_parser(__doc__, RUNS, 900, "training_renderer")
    ap.add_argument("--seeds", default="4,5", help="comma-separated training seeds (4: the config's)")
    ap.add_argument("--skip-reference", action="store_true")
    args = ap.parse_args()
    names = study_runs(ap, args, RUNS)
    untrained = []
    if args.skip_reference:
        untrained = [n for n in names if n == "reference"]
        names = [n for n in names if n != "reference"]
    seeds = [int(x) for x in args.seeds.split(",")]

    def folder(name: str, seed: int) -> Path:
        return args.work / (name if seed == 4 else f"{name}-seed{seed}")

    for seed in seeds:
        for name in names:
            out = folder(name, seed)
            if args.eval_only or (out / "networks.pt").exists():
                continue
            args.seed = seed
            train(name, out, args)
    args.seed = seeds[0]
    # Every run's cost per step, measured the same way in one window after training (the runs
    # themselves may have shared the machine with other work).
    probed = {} if args.quick or args.no_probe else {n: probe_seconds_per_step(n, args) for n in names + untrained}

    import mitsvbrdf as ms
    from mitsvbrdf.data.procedural import generate
    from mitsvbrdf.training.config import TEST_SEED_BASE

    rig = ms.Rig.from_scene()
    held_out = generate(args.eval_n, size=args.size, seed=TEST_SEED_BASE)
    materials = [held_out[i] for i in range(args.eval_n)]
    keys = ["rmse_average"] + ["rmse_" + m for m in MAPS]
    scores: dict[str, dict[str, list[float]]] = {}  # run -> key -> values over (seed, material)
    for name in names:
        done = [folder(name, s) for s in seeds if (folder(name, s) / "networks.pt").exists()]
        if len(done) < len(seeds):
            print(f"{name}: {len(seeds) - len(done)} of its seeds have no networks.pt, skipped", flush=True)
            continue
        scores[name] = {k: [] for k in keys}
        for out in done:
            for k, v in score(out / "networks.pt", materials, rig).items():
                scores[name][k] += v
    rows = score_rows(scores, probed)
    lines = ["Command: `python benchmarks/training_renderer.py " + " ".join(sys.argv[1:]) + "`", "",
             f"G_sc (fixed MonoGrad, {args.size} px, width {args.width}, {args.steps} steps, batch 4, seeds "
             f"{args.seeds}) trained on captures from each renderer; map RMSE (encoded maps) on {args.eval_n} held-out "
             f"procedural materials whose captures come from the reference renderer, mean over seeds and materials "
             f"({torch.get_num_threads()} threads for the step times).", "", *table_lines(rows, keys, "training renderer")]
    for name in untrained:
        sec = f"{probed[name]:.3f}" if name in probed else ""
        lines.append(f"| {name} (not trained) | {sec} | " + " | ".join("-" for _ in keys) + " |")
    for name in untrained:
        if name in probed:
            lines += ["", f"{name}: {args.steps} steps would take about {args.steps * probed[name] / 60:.0f} "
                          f"minutes per seed on this machine; left out (--skip-reference)."]
    if DEFAULT_RUN in scores and len(scores) > 1:
        lines += ["", f"Paired differences against {DEFAULT_RUN} (the default integrator), over the same seeds and "
                      f"materials: mean +- standard error; negative means lower error than {DEFAULT_RUN}.", "",
                  *paired_lines(scores, DEFAULT_RUN, keys)]
    if rows:
        best = min(rows, key=lambda r: r["rmse_average"])
        lines += ["", f"Lowest average map RMSE: {best['run']} ({best['rmse_average']:.4f})."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from report import write_report

    write_report(args.out, "training_renderer", "Training renderer study", "training_renderer.py", text, rows)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", str(os.cpu_count() or 1))
    main()
