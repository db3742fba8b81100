"""Summarise training runs: does the loss decrease? Reads RUN/metrics.csv of each run given.

    .venv/bin/python benchmarks/training_log.py runs/init-small runs/stage1-small ...

Prints, per run, the mean of each loss term over the first and the last 10% of the logged steps,
copies each run's metrics.csv and config.json to docs/benchmarks/training_runs/<run>/ and draws its
loss.png there from metrics.csv (mitsvbrdf.training.loss_plot: raw and running mean); writes
docs/benchmarks/training_log.md (+ CSV).
"""

from __future__ import annotations

import argparse
import csv
import shutil
from pathlib import Path

from mitsvbrdf.training.loss_plot import NOT_LOSSES, write_loss_plot
from report import write_report

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run folders (default: every runs/* with a metrics.csv)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    ap.add_argument("--about", default="", help="a sentence on what the runs are, printed under the command")
    args = ap.parse_args()
    runs = args.runs or sorted(p.parent for p in (ROOT / "runs").glob("*/metrics.csv"))
    if not runs:
        raise SystemExit("no training runs found (train first, see docs/training.md)")
    rows = []
    for run in runs:
        with open(run / "metrics.csv") as f:
            hist = list(csv.DictReader(f))
        k = max(1, len(hist) // 10)
        for key in hist[0]:
            if key in NOT_LOSSES:
                continue
            first = sum(float(h[key]) for h in hist[:k]) / k
            last = sum(float(h[key]) for h in hist[-k:]) / k
            rows.append({"run": run.name, "term": key, "steps": hist[-1]["step"], "first_10pct": round(first, 5),
                         "last_10pct": round(last, 5), "ratio": round(last / first, 3) if first else float("nan")})
        dest = args.out / "training_runs" / run.name
        dest.mkdir(parents=True, exist_ok=True)
        for name in ("metrics.csv", "config.json"):
            src, dst = run / name, dest / name
            if src.exists() and not (dst.exists() and dst.samefile(src)):  # re-run on the copies: kept
                shutil.copy(src, dst)
        write_loss_plot(hist, dest / "loss.png", run.name)
    # run folders by name only: where they lay on the machine that trained them is not the point
    about = f"{args.about} " if args.about else ""
    text = ("Command: `python benchmarks/training_log.py " + " ".join(f".../{r.name}" for r in runs)
            + (f" --about '{args.about}'" if args.about else "") + "`\n\n" + about +
            "Mean of each logged loss term over the first and the last 10% of the logged steps "
            "(each run's metrics.csv is copied to training_runs/, beside its loss curves, loss.png).\n\n"
            "| run | term | steps | first 10% | last 10% | last / first |\n|---|---|---:|---:|---:|---:|\n" +
            "\n".join(f"| {r['run']} | {r['term']} | {r['steps']} | {r['first_10pct']} | {r['last_10pct']} | "
                      f"{r['ratio']} |" for r in rows) + "\n")
    print(text)
    write_report(args.out, "training_log", "Training runs: loss over the run", "training_log.py", text, rows)


if __name__ == "__main__":
    main()
