"""Compare two evaluations of the same materials, material by material, from their metrics.csv.

    .venv/bin/python benchmarks/paired_metrics.py A/metrics.csv B/metrics.csv --names a,b [--out DIR]

For exports that no longer exist side by side: ``mitsvbrdf evaluate --adaptive`` pairs two exports
in one run, but a run folder does not outlive its session, while the metrics.csv of a scored export is
committed beside its notes (docs/evaluation/*/). Each file's ``--method`` rows (default: adaptive,
the method every evaluation scores) are taken under the given name; materials both files scored are
paired by name (e.g. "procedural:1000000:7": the same held-out maps), the others are left out and
counted. Prints each map's mean RMSE per file and the paired differences B - A (mean +- standard
error over the materials, and on how many A is lower), as `mitsvbrdf evaluate` prints them for
methods of one run; with ``--out``, writes them to DIR/summary.md.

The captures of the two evaluations are not the same renders when the exports predict different
patterns, so each difference carries both exports' capture noise: the standard error includes it.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from mitsvbrdf.evaluation import HEADS, MAP_COLUMNS, paired_table, summarize


def read_rows(path: Path, method: str, name: str) -> list[dict]:
    """The rows of one metrics.csv scored for ``method``, relabelled ``name``, scores as numbers.
    ValueError when the file has none (a file of another method set, or an empty run)."""
    with open(path, newline="") as f:
        rows = [{k: float(v) for k, v in r.items() if k not in ("method", "material")}
                | {"method": name, "material": r["material"]} for r in csv.DictReader(f) if r["method"] == method]
    if not rows:
        raise ValueError(f"{path} has no rows of method {method!r}")
    return rows


def compare(a: list[dict], b: list[dict], names: tuple[str, str]) -> str:
    """Markdown: each side's mean map RMSE over the materials both scored, and the paired table."""
    common = {r["material"] for r in a} & {r["material"] for r in b}
    if not common:
        raise ValueError(f"{names[0]} and {names[1]} scored no material in common")
    rows = [r for r in a + b if r["material"] in common]
    left_out = len({r["material"] for r in a + b}) - len(common)
    lines = [f"Mean map RMSE over the {len(common)} materials both evaluations scored"
             + (f" ({left_out} scored by one only, left out)" if left_out else "") + ":", "",
             "| Evaluation | " + " | ".join(HEADS[c] for c in MAP_COLUMNS) + " |",
             "|---|" + "---:|" * len(MAP_COLUMNS)]
    lines += [f"| {s['method']} | " + " | ".join(f"{s[c]:.4f}" for c in MAP_COLUMNS) + " |" for s in summarize(rows)]
    return "\n".join(lines + [""] + paired_table(rows, list(names))) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("a", type=Path, help="metrics.csv of the reference evaluation")
    ap.add_argument("b", type=Path, help="metrics.csv of the evaluation compared with it")
    ap.add_argument("--names", default="a,b", help="the two evaluations' names in the tables, comma-separated")
    ap.add_argument("--method", default="adaptive", help="which method's rows of each file to compare")
    ap.add_argument("--out", type=Path, help="also write the tables to OUT/summary.md")
    args = ap.parse_args()
    names = tuple(args.names.split(","))
    if len(names) != 2 or names[0] == names[1]:
        raise SystemExit(f"--names takes two different names, got {args.names!r}")
    try:
        text = compare(read_rows(args.a, args.method, names[0]), read_rows(args.b, args.method, names[1]), names)
    except (OSError, ValueError) as e:
        raise SystemExit(str(e))
    print(text, end="")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        # a relative path as given; of an absolute one, no more than its folder: machines differ above it
        shown = [str(p) if not p.is_absolute() else f".../{p.parent.name}/{p.name}" for p in (args.a, args.b)]
        (args.out / "summary.md").write_text(f"Command: `python benchmarks/paired_metrics.py {shown[0]} {shown[1]} "
                                             f"--names {args.names}`\n\n{text}")


if __name__ == "__main__":
    main()
