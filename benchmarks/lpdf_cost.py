"""What an L_pdf costs and how wrong it is: texel stride against quadrature orders.

    .venv/bin/python benchmarks/lpdf_cost.py                 # writes docs/benchmarks/lpdf_cost.{md,csv,png}
    .venv/bin/python benchmarks/lpdf_cost.py --quick         # 32 px, 2 settings; nothing written

L_pdf (:func:`mitsvbrdf.importance.importance`, Eq. 2-3) of ``--n`` procedural materials, for
each texel stride and quadrature orders (cell_order q, lobe_grid m of
:class:`~mitsvbrdf.render.quadrature.QuadratureSettings`), against a dense reference (stride 1,
orders (4, 64)): the relative L1 error of the normalised L_pdf (mean |L - L_ref| / mean L_ref per
material; median and worst over materials) and the seconds for a batch of 4 materials (the
training batch; mean of ``--repeats`` after a warm-up call, ``torch.get_num_threads()`` threads).
Run it on a quiet machine: the times are the point.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = (1, 4, 64)  # stride, cell_order, lobe_grid
SETTINGS = [(4, 2, 32), (4, 2, 16), (4, 1, 32), (4, 1, 16), (4, 1, 8), (2, 2, 32), (2, 1, 16), (2, 1, 8),
            (1, 1, 16)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="64,128")
    ap.add_argument("--n", type=int, default=8, help="materials scored (the first 4 are timed)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    settings = SETTINGS
    sizes = [int(s) for s in args.sizes.split(",")]
    if args.quick:
        sizes, settings, args.n, args.repeats = [32], SETTINGS[:1] + SETTINGS[3:4], 4, 1

    import mitsvbrdf as ms
    from mitsvbrdf.data.procedural import generate
    from mitsvbrdf.importance import importance
    from mitsvbrdf.render.quadrature import QuadratureSettings

    rig = ms.Rig.from_scene()

    def lpdf(m, stride, q, g):
        return importance(m.normal, m.roughness, rig, texel_stride=stride, settings=QuadratureSettings(q, g))

    rows = []
    for size in sizes:
        mats = generate(args.n, size=size, seed=77)
        ref = lpdf(mats, *REFERENCE)
        timed = mats[:4] if args.n > 4 else mats
        for stride, q, g in settings:
            lpdf(timed, stride, q, g)
            t0 = time.perf_counter()
            for _ in range(args.repeats):
                lpdf(timed, stride, q, g)
            sec = (time.perf_counter() - t0) / args.repeats
            err = (lpdf(mats, stride, q, g) - ref).abs().mean((1, 2, 3)) / ref.mean((1, 2, 3))
            row = {"size": size, "stride": stride, "cell_order": q, "lobe_grid": g, "seconds_4": round(sec, 4),
                   "rel_l1_median": round(float(err.median()), 4), "rel_l1_max": round(float(err.max()), 4)}
            rows.append(row)
            print(row, flush=True)
    default = {(r["size"]): r for r in rows if (r["stride"], r["cell_order"], r["lobe_grid"]) == SETTINGS[0]}
    lines = ["Command: `python benchmarks/lpdf_cost.py " + " ".join(sys.argv[1:]) + "`", "",
             f"L_pdf of {args.n} procedural materials (seed 77) against a dense reference (stride {REFERENCE[0]}, "
             f"orders ({REFERENCE[1]}, {REFERENCE[2]})); seconds for 4 materials on {torch.get_num_threads()} "
             f"threads. The first row per size is the renderer's orders at the trained stride (the old default).", "",
             "| px | stride | cell_order | lobe_grid | s / 4 materials | x default | rel. L1 median | rel. L1 worst |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        ratio = r["seconds_4"] / default[r["size"]]["seconds_4"]
        lines.append(f"| {r['size']} | {r['stride']} | {r['cell_order']} | {r['lobe_grid']} | {r['seconds_4']:.3f} | "
                     f"{ratio:.2f} | {r['rel_l1_median']:.3f} | {r['rel_l1_max']:.3f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(sizes), figsize=(5 * len(sizes), 4), squeeze=False)
    for ax, size in zip(axes[0], sizes):
        for r in (r for r in rows if r["size"] == size):
            ax.scatter(r["seconds_4"], r["rel_l1_median"], color=f"C{r['stride']}")
            ax.annotate(f"s{r['stride']} ({r['cell_order']},{r['lobe_grid']})", (r["seconds_4"], r["rel_l1_median"]),
                        fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set(xscale="log", yscale="log", xlabel="seconds / 4 materials", ylabel="median relative L1 error",
               title=f"L_pdf at {size} px (s = texel stride)")
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out / "lpdf_cost.png", dpi=110)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from report import write_report

    write_report(args.out, "lpdf_cost", "L_pdf: cost against error", "lpdf_cost.py",
                 text + "\n![error vs time](lpdf_cost.png)\n", rows)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", str(os.cpu_count() or 1))
    main()
