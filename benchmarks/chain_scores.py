"""One table of scored chains, read from the records and summaries committed beside each run.

    .venv/bin/python benchmarks/chain_scores.py docs/evaluation/chain-scratch-gsc docs/evaluation/chain-15:c15 [--out FILE]

A run's folder under docs/evaluation/ holds what its session committed: ``records/chain.json`` (the
record ``mitsvbrdf train-chain`` writes: chain file, time budget, steps per stage), one demo record
``demo-*.json`` (``mitsvbrdf demo``: the bundled material at 256 px) and the ``summary.csv`` of
``mitsvbrdf evaluate`` for each scored set (``samples-256/``: the 4 shared sample materials,
``procedural-256/`` and ``procedural-64/``: 32 held-out procedural materials). Prints one markdown
row per folder: its budget, the initializer's steps and G_sc's (stage 2 and fine-tuning), and each
set's average map RMSE with the normal RMSE in brackets. Scores within the training issue's goals
(its "Must show": demo <= 0.035 with normal <= 0.05, procedural 256 px <= 0.045 with normal <= 0.035,
sample materials <= 0.05) are in bold, a pair in bold only where both parts meet theirs.

``DIR:METHOD`` takes the METHOD row of summaries that score several exports side by side (e.g.
``c15`` in chain-15/, whose ``adaptive`` row is chain 14); without it a summary must have one row.
A set a folder lacks is shown as "-". For a chain continued from an earlier export (chain-15/ and
the other continued chains), budget and steps are the continuation's alone. The numbers are the
committed ones, not recomputed: a folder is only as current as its session left it.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

# set -> (goal on the average map RMSE, goal on the normal RMSE); None: no goal. The demo's scores
# are in its record; every other set's in the folder of its name.
GOALS = {
    "demo": (0.035, 0.05),
    "samples-256": (0.05, None),
    "procedural-256": (0.045, 0.035),
    "procedural-64": (None, None),
}
GSC_STAGES = ("stage2", "finetune")  # the stages that train G_sc (stage 1 trains G_ad behind it)


def parse_run(arg: str) -> tuple[Path, str | None]:
    """``DIR`` or ``DIR:METHOD``."""
    folder, _, method = arg.partition(":")
    return Path(folder), method or None


def summary_scores(path: Path, method: str | None) -> tuple[float, float] | None:
    """(average, normal) RMSE of ``method``'s row of a summary.csv; None when there is no file.
    ValueError when the method has no row, or none was named and the file has several."""
    if not path.is_file():
        return None
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    methods = [r["method"] for r in rows]
    if method is None and len(rows) != 1:
        raise ValueError(f"{path} scores {', '.join(methods)}: name one as DIR:METHOD")
    row = rows[0] if method is None else next((r for r in rows if r["method"] == method), None)
    if row is None:
        raise ValueError(f"{path} has no row of method {method!r} (it has {', '.join(methods)})")
    return float(row["rmse_average"]), float(row["rmse_normal"])


def demo_scores(folder: Path) -> tuple[float, float] | None:
    """(average, normal) RMSE of the folder's demo record; None without one, ValueError with several."""
    records = sorted(folder.glob("demo-*.json"))
    if len(records) > 1:
        raise ValueError(f"{folder} has {len(records)} demo records ({', '.join(p.name for p in records)}): "
                         "the table takes a folder with one")
    if not records:
        return None
    metrics = json.loads(records[0].read_text())["metrics"]
    return float(metrics["rmse_average"]), float(metrics["rmse_normal"])


def chain_steps(folder: Path) -> dict:
    """Budget (minutes), chain file, and steps of the initializer and of G_sc from records/chain.json."""
    path = folder / "records" / "chain.json"
    if not path.is_file():
        raise ValueError(f"{folder} has no records/chain.json")
    record = json.loads(path.read_text())
    steps = {s["stage"]: int(s["steps"]) for s in record["stages"]}
    return {"minutes": record["time_budget_s"] / 60, "chain": Path(record["chain"]).name,
            "init": steps.get("init"), "gsc": sum(steps.get(s, 0) for s in GSC_STAGES)}


def cell(scores: tuple[float, float] | None, goals: tuple[float | None, float | None]) -> str:
    """'avg (normal)', bold when every goal the set has is met."""
    if scores is None:
        return "-"
    text = f"{scores[0]:.4f} ({scores[1]:.4f})"
    met = all(g is None or s <= g for s, g in zip(scores, goals))
    return f"**{text}**" if met and any(g is not None for g in goals) else text


def table(runs: list[tuple[Path, str | None]]) -> str:
    """The markdown table, one row per run, the goals in the last row."""
    lines = ["| run | chain file | budget (min) | init steps | G_sc steps | "
             + " | ".join(GOALS) + " |", "|---|---|---:|---:|---:|" + "---:|" * len(GOALS)]
    for folder, method in runs:
        steps = chain_steps(folder)
        scores = [demo_scores(folder)] + [summary_scores(folder / name / "summary.csv", method)
                                          for name in list(GOALS)[1:]]
        label = folder.name + (f":{method}" if method else "")
        init = "-" if steps["init"] is None else str(steps["init"])
        lines.append(f"| {label} | {steps['chain']} | {steps['minutes']:.0f} | {init} | {steps['gsc']} | "
                     + " | ".join(cell(s, goals) for s, goals in zip(scores, GOALS.values())) + " |")
    goal_cells = ["-" if a is None else f"<= {a}" + ("" if n is None else f" (<= {n})") for a, n in GOALS.values()]
    lines.append("| goal | | | | | " + " | ".join(goal_cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders (DIR or DIR:METHOD), one row each, in this order")
    ap.add_argument("--out", type=Path, help="also write the table, under the command, to this file")
    args = ap.parse_args()
    try:
        text = table([parse_run(a) for a in args.runs])
    except (OSError, ValueError) as e:
        raise SystemExit(f"chain_scores: {e}")
    except KeyError as e:
        raise SystemExit(f"chain_scores: a record lacks the field {e}")
    print(text, end="")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(f"Command: `python benchmarks/chain_scores.py {' '.join(args.runs)}`\n\n{text}")


if __name__ == "__main__":
    main()
