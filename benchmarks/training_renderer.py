"""Which renderer should G_sc learn from? The same G_sc trained on captures from each renderer,
scored on the same held-out materials rendered by the reference renderer.

    .venv/bin/python benchmarks/training_renderer.py                 # trains, scores, writes docs/benchmarks/training_renderer.*
    .venv/bin/python benchmarks/training_renderer.py --eval-only     # re-score finished runs
    .venv/bin/python benchmarks/training_renderer.py --quick         # smoke run (tiny), nothing written

Every run is ``train/fixed-monograd-small.toml`` (the MonoGrad baseline: G_sc with fixed
patterns) at ``--size`` px, width ``--width``, ``--steps`` steps, batch 4, seed 4 (same data
stream, same initialisation); only the renderer of the training captures differs:

* ``mitsuba-plain``: the ``importance`` integrator as it was (independent samples, no control
  variate), 4 spp;
* ``mitsuba-cv``: the default integrator (stratified samples, diffuse + LTC control variate), 4 spp;
* ``ltc-prefiltered``: the paper's training renderer (noise-free, biased);
* ``reference``: the deterministic quadrature (clean and unbiased; the slowest), unless
  ``--skip-reference``.

Each run is scored on ``--eval-n`` held-out procedural materials (seeds >= 1_000_000, never seen
in training) whose MonoGrad captures come from the reference renderer: map RMSE on encoded maps
per map and average, as ``mitsvbrdf evaluate`` reports it. The table also gives each run's seconds
per training step (measured in the run, on this machine).
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

from mitsvbrdf.capture.scene_file import write_integrator_options

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "train" / "fixed-monograd-small.toml"
MAPS = ("normal", "diffuse", "roughness", "specular")

#: name -> (overrides of the config, integrator options written into a copy of the scene file or None)
RUNS = {
    "mitsuba-plain": (["render.method=\"mitsuba\"", "render.spp=4"],
                      {"sampler": "independent", "control_variate": "none"}),
    "mitsuba-cv": (["render.method=\"mitsuba\"", "render.spp=4"], None),
    "ltc-prefiltered": (["render.method=\"ltc\"", "render.ltc_mode=\"prefiltered\""], None),
    "reference": (["render.method=\"reference\""], None),
}


def train(name: str, out: Path, args) -> float:
    """Train run ``name`` into ``out`` (resuming an interrupted run); returns its wall seconds."""
    overrides, options = RUNS[name]
    sets = [f"out=\"{out}\"", f"data.size={args.size}", f"model.svbrdf_width={args.width}",
            f"train.steps={args.steps}", "train.batch=4", "seed=4",
            f"train.checkpoint_every={min(100, args.steps)}", f"train.log_every={min(10, args.steps)}", *overrides]
    if options is not None:
        scene = write_integrator_options(ROOT / "scenes" / "lcd_rig.xml", out.parent / f"{name}.xml", **options)
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


def seconds_per_step(out: Path) -> float:
    """Median seconds per step over the run's logged intervals (metrics.csv)."""
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    per = sorted(1.0 / float(r["it_per_s"]) for r in rows if float(r.get("it_per_s") or 0) > 0)
    return per[len(per) // 2] if per else float("nan")


def score(networks: Path, materials, rig) -> dict[str, float]:
    """Map RMSE (encoded maps) per map and average over ``materials``: each captured under the
    run's patterns by the reference renderer (clean and unbiased), reconstructed by its G_sc."""
    from mitsvbrdf.metrics import map_rmse
    from mitsvbrdf.nets import network_from_record
    from mitsvbrdf.nets.io import read_network_file
    from mitsvbrdf.pipeline import maps_to_svbrdf
    from mitsvbrdf.render import render
    from mitsvbrdf.separation import reconstruct_maps

    recs = read_network_file(networks, "baseline networks")
    net = network_from_record(recs["svbrdf"], "svbrdf").eval()
    pats = network_from_record(recs["patterns"], "patterns")().detach()
    sums = dict.fromkeys(MAPS, 0.0)
    with torch.no_grad():
        for gt in materials:
            pred = maps_to_svbrdf(reconstruct_maps(net, render(gt, pats, rig, method="reference"), pats, rig))
            for k, v in map_rmse(pred, gt).items():
                if k in sums:
                    sums[k] += float(v[0])
    out = {f"rmse_{k}": v / len(materials) for k, v in sums.items()}
    out["rmse_average"] = sum(out.values()) / len(MAPS)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--width", type=int, default=16)
    ap.add_argument("--eval-n", type=int, default=16)
    ap.add_argument("--runs", default=",".join(RUNS), help="comma-separated subset of " + ", ".join(RUNS))
    ap.add_argument("--skip-reference", action="store_true")
    ap.add_argument("--eval-only", action="store_true")
    ap.add_argument("--quick", action="store_true", help="3 steps at 16 px, 2 materials; nothing written")
    ap.add_argument("--work", type=Path, default=ROOT / "runs" / "training_renderer")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    names = [n for n in args.runs.split(",") if n]
    unknown = [n for n in names if n not in RUNS]
    if unknown:
        ap.error(f"unknown runs {unknown}; available: {', '.join(RUNS)}")
    if args.skip_reference:
        names = [n for n in names if n != "reference"]
    if args.quick:
        args.steps, args.size, args.width, args.eval_n = 3, 16, 4, 2
        args.work = args.work.parent / (args.work.name + "-quick")
    for name in names:
        out = args.work / name
        if args.eval_only or (out / "networks.pt").exists():
            continue
        train(name, out, args)

    import mitsvbrdf as ms
    from mitsvbrdf.data.procedural import generate
    from mitsvbrdf.training.config import TEST_SEED_BASE

    rig = ms.Rig.from_scene()
    held_out = generate(args.eval_n, size=args.size, seed=TEST_SEED_BASE)
    materials = [held_out[i] for i in range(args.eval_n)]
    rows = []
    for name in names:
        out = args.work / name
        if not (out / "networks.pt").exists():
            print(f"{name}: no networks.pt in {out}, skipped", flush=True)
            continue
        row = {"run": name, "seconds_per_step": round(seconds_per_step(out), 3)}
        row.update({k: round(v, 5) for k, v in score(out / "networks.pt", materials, rig).items()})
        rows.append(row)
        print(row, flush=True)
    keys = ["rmse_average"] + ["rmse_" + m for m in MAPS]
    lines = [f"G_sc (fixed MonoGrad, {args.size} px, width {args.width}, {args.steps} steps, batch 4, seed 4) "
             f"trained on captures from each renderer; map RMSE (encoded maps) on {args.eval_n} held-out "
             f"procedural materials whose captures come from the reference renderer "
             f"({torch.get_num_threads()} threads for the step times).", "",
             "| training renderer | s / step | " + " | ".join(k.replace("rmse_", "") for k in keys) + " |",
             "|---|---:|" + "---:|" * len(keys)]
    lines += [f"| {r['run']} | {r['seconds_per_step']} | " + " | ".join(f"{r[k]:.4f}" for k in keys) + " |"
              for r in rows]
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
