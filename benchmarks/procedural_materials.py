"""Procedural materials: coverage statistics over many materials, and generation throughput.

Prints markdown tables and writes them (plus a CSV of the throughput rows) to docs/benchmarks/.
Run:

    .venv/bin/python benchmarks/procedural_materials.py            # 1000 materials at 256 px
    .venv/bin/python benchmarks/procedural_materials.py --quick    # 120 materials at 64 px
    .venv/bin/python benchmarks/procedural_materials.py --stem procedural_coverage_h100   # another machine

Coverage: materials 0..n-1 of stream seed 0 (every family equally often), per-texel histograms of
roughness, specular albedo (mean of RGB), diffuse luminance and normal slope angle, and a per-family
table of the same quantities (1st / 99th percentiles over the family's texels) so a missing range
or a missing family shows. Throughput: wall-clock materials per second for batches of 32 at
256 x 256 (median of repeats after a warm-up): one call of ``generate`` with torch's default
intra-op threads and with one thread, a DataLoader over ``ProceduralDataset`` with workers, and on
CUDA when present (synchronised).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from mitsvbrdf.data import procedural, stats
from mitsvbrdf.data.datasets import ProceduralDataset
from report import write_report

ROOT = Path(__file__).resolve().parent.parent

EDGES = {
    "roughness": [0.0, 0.03, 0.06, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.0],
    "ks": [0.0, 0.02, 0.04, 0.06, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0],
    "kd_luminance": [0.0, 0.01, 0.03, 0.1, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0],
    "slope_deg": [0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0],
}
LABELS = {"roughness": "roughness r", "ks": "ks (RGB mean)", "kd_luminance": "kd luminance",
          "slope_deg": "slope angle (deg)"}


def coverage(n: int, size: int, batch: int, threads: int | None) -> tuple[dict, dict, list[str], float]:
    """Histograms (fractions of all texels) and per-family percentile ranges of n materials."""
    hist = {k: [0.0] * (len(e) - 1) for k, e in EDGES.items()}
    per_family: dict[str, dict[str, list[torch.Tensor]]] = {}
    fams: list[str] = []
    t0 = time.perf_counter()
    for s in range(0, n, batch):
        m = procedural.generate(min(batch, n - s), size=size, seed=0, start=s, threads=threads)
        vals = stats.texel_maps(m)
        w = m.batch_size / n
        for k, e in EDGES.items():
            hist[k] = [a + w * b for a, b in zip(hist[k], stats.histogram(vals[k], e))]
        sub = torch.tensor([0.01, 0.5, 0.99])
        for b in range(m.batch_size):
            fam = procedural.family_of(s + b, 0)
            fams.append(fam)
            d = per_family.setdefault(fam, {k: [] for k in (*stats.QUANTITIES, "slope_max")})
            for k in stats.QUANTITIES:
                flat = vals[k][b].reshape(-1)[:: max(1, size * size // 16384)].float().cpu()
                d[k].append(torch.quantile(flat, sub))
            d["slope_max"].append(vals["slope_deg"][b].max().cpu())
    return hist, per_family, fams, time.perf_counter() - t0


def _median_rate(fn, count: int, repeats: int, sync=None) -> float:
    fn(0)  # warm-up
    times = []
    for r in range(repeats):
        if sync:
            sync()
        t0 = time.perf_counter()
        fn(r + 1)
        if sync:
            sync()
        times.append(time.perf_counter() - t0)
    return count / statistics.median(times)


def throughput(batch: int, size: int, repeats: int, workers: list[int]) -> list[dict]:
    rows = []
    default_threads = torch.get_num_threads()
    for threads in sorted({1, 2, default_threads}):
        rate = _median_rate(lambda r: procedural.generate(batch, size, seed=r, threads=threads), batch, repeats)
        rows.append({"device": "cpu", "mode": "generate()", "threads": threads, "workers": 0,
                     "batch": batch, "size": size, "materials_per_s": round(rate, 1)})
        print(f"cpu generate() threads={threads}: {rate:.1f} materials/s", flush=True)
    for w in workers:
        n_batches = repeats + 2
        ds = ProceduralDataset(batch * n_batches, size=size, seed=11)
        loader = DataLoader(ds, batch_size=batch, num_workers=w, persistent_workers=False)
        it = iter(loader)
        next(it)  # workers started, first batch out
        t0 = time.perf_counter()
        count = 0
        for b in it:
            count += b["normal"].shape[0]
        rate = count / (time.perf_counter() - t0)
        rows.append({"device": "cpu", "mode": "DataLoader", "threads": 1, "workers": w, "batch": batch,
                     "size": size, "materials_per_s": round(rate, 1)})
        print(f"cpu DataLoader workers={w} (1 thread each): {rate:.1f} materials/s", flush=True)
    if torch.cuda.is_available():
        for b in (batch, 8 * batch):
            rate = _median_rate(lambda r: procedural.generate(b, size, seed=r, device="cuda"), b, repeats,
                                sync=torch.cuda.synchronize)
            rows.append({"device": "cuda", "mode": "generate()", "threads": default_threads, "workers": 0,
                         "batch": b, "size": size, "materials_per_s": round(rate, 1)})
            print(f"cuda generate() batch={b}: {rate:.1f} materials/s", flush=True)
    return rows


def _pct(x: float) -> str:
    return f"{100 * x:.1f}" if x >= 0.0005 else ("0" if x == 0 else "<0.1")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1000, help="materials for the coverage statistics")
    ap.add_argument("--size", type=int, default=256, help="resolution for the coverage statistics")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--workers", type=int, nargs="*", default=None,
                    help="DataLoader worker counts to time (default: 2 and the CPU count, at most 8)")
    ap.add_argument("--quick", action="store_true", help="120 materials at 64 px, 2 repeats")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    ap.add_argument("--stem", default="procedural_coverage", help="output file stem")
    args = ap.parse_args()
    if args.quick:
        args.n, args.size, args.repeats = 120, 64, 2
    cpus = os.cpu_count() or 1
    workers = args.workers if args.workers is not None else sorted({min(2, cpus), min(8, cpus)})
    machine = (f"{platform.machine()}, {cpus} CPUs, torch {torch.__version__}, default intra-op threads "
               f"{torch.get_num_threads()}" + (f", GPU {torch.cuda.get_device_name()}" if torch.cuda.is_available() else ""))
    print(machine, flush=True)

    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    rows = throughput(32, 256, args.repeats, workers)
    load_after = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    hist, per_family, fams, cov_s = coverage(args.n, args.size, batch=50, threads=1)

    lines = [f"Machine: {machine}.", "",
             "Contact sheet of materials 24-47 (normal | diffuse | roughness | specular | reference render under a "
             "uniform pattern): [procedural_preview.png](procedural_preview.png), made with `python -m mitsvbrdf "
             "materials preview --n 24 --start 24 --tile 96 --columns 3 --out docs/benchmarks/procedural_preview.png`.",
             "",
             "## Throughput (256 x 256, materials per second, median of "
             f"{args.repeats} batches after a warm-up; target >= 50/s on CPU for a batch of 32)", "",
             "| device | mode | intra-op threads | workers | batch | materials/s |", "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['device']} | {r['mode']} | {r['threads']} | {r['workers']} | {r['batch']} | "
                     f"**{r['materials_per_s']}** |")
    lines += ["", f"System load average (1 min) before / after the timings: {load_before:.1f} / {load_after:.1f} "
              f"on {cpus} CPUs (other processes share the machine; the multi-threaded figure swings most with it).",
              "", "The generator is many small tensor ops per material: torch's intra-op threads help little and, on a "
              "machine whose cores are busy with other processes, cost a lot (threads wait for each other at every "
              "op); one thread per process (the default of `generate`) and DataLoader workers scale instead.", ""]
    lines += [f"## Coverage: {args.n} materials at {args.size} x {args.size} (stream seed 0; "
              f"generated in {cov_s:.1f} s with one thread)", "",
              "Fraction of all texels (%) per bin; bins are [lower, upper).", ""]
    for k, e in EDGES.items():
        head = " | ".join(f"{e[i]:g}-{e[i + 1]:g}" for i in range(len(e) - 1))
        lines += [f"**{LABELS[k]}**", "", f"| {head} |", "|" + "---:|" * (len(e) - 1),
                  "| " + " | ".join(_pct(x) for x in hist[k]) + " |", ""]
    lines += ["## Per family", "",
              "Ranges over the family's materials: lowest 1st percentile - highest 99th percentile of the texels, "
              "and the median of the materials' medians in brackets; slope: median of the materials' 99th "
              "percentile and the steepest texel.", "",
              "| family | materials | roughness | ks | ks chroma (max) | kd luminance | slope p99 / max (deg) |",
              "|---|---:|---|---|---:|---|---|"]
    for fam in procedural.FAMILIES:
        d = per_family.get(fam)
        if d is None:
            lines.append(f"| {fam} | 0 | MISSING | | | | |")
            continue
        q = {k: torch.stack(v) for k, v in d.items() if k != "slope_max"}

        def rng(k: str) -> str:
            return f"{float(q[k][:, 0].min()):.3f} - {float(q[k][:, 2].max()):.3f} ({float(q[k][:, 1].median()):.3f})"

        smax = float(torch.stack(d["slope_max"]).max())
        lines.append(f"| {fam} | {fams.count(fam)} | {rng('roughness')} | {rng('ks')} | "
                     f"{float(q['ks_chroma'][:, 2].max()):.2f} | {rng('kd_luminance')} | "
                     f"{float(q['slope_deg'][:, 2].median()):.1f} / {smax:.1f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    write_report(args.out, args.stem, "Procedural materials: coverage and throughput", "procedural_materials.py",
                 text, rows)


if __name__ == "__main__":
    main()
