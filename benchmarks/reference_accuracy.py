"""Reference renderer: time per image and error against a 4x denser quadrature, per roughness.

Prints a markdown table and writes it (plus CSV) to docs/benchmarks/. Run:

    .venv/bin/python benchmarks/reference_accuracy.py            # full (a few minutes on 2 cores)
    .venv/bin/python benchmarks/reference_accuracy.py --quick    # smaller, for a smoke check

Materials: the bundled example's normal and diffuse maps with a constant roughness r and
ks = 0.04 (dielectric) so every roughness is seen through real normal variation; patterns: the
5 MonoGrad patterns and 5 random patterns (sharp cell edges everywhere). Errors are relative RMSE
over all pixels and patterns, and the worst pixel's error relative to the image's 99th percentile.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.patterns import monograd, random
from report import write_report

ROOT = Path(__file__).resolve().parent.parent


def material(size: int, roughness: float) -> ms.SVBRDF:
    base = ms.SVBRDF.load(DEFAULT_MATERIAL).resized(size)
    return ms.SVBRDF(normal=base.normal, diffuse=base.diffuse,
                     roughness=torch.full_like(base.roughness, roughness),
                     specular=torch.full_like(base.specular, 0.04))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--time-resolution", type=int, default=256)
    ap.add_argument("--error-resolution", type=int, default=64)
    ap.add_argument("--quick", action="store_true", help="32 px and fewer roughness values")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    if args.quick:
        args.time_resolution, args.error_resolution = 64, 32
    torch.set_num_threads(torch.get_num_threads())
    rig = ms.Rig.from_scene()
    default = ms.QuadratureSettings()
    dense = default.denser()
    pats = torch.cat([monograd(), random(n=5, seed=0)])

    # Time: one 256x256 image set under the 5 MonoGrad patterns at the default accuracy.
    m = material(args.time_resolution, 0.3)
    with torch.no_grad():
        ms.render(material(16, 0.3), monograd(), rig)  # warm-up
        t0 = time.perf_counter()
        ms.render(m, monograd(), rig)
        seconds = time.perf_counter() - t0

    rows = []
    for r in ([0.01, 0.1, 1.0] if args.quick else [0.001, 0.01, 0.1, 0.5, 1.0]):
        m = material(args.error_resolution, r)
        with torch.no_grad():
            t0 = time.perf_counter()
            a = ms.render(m, pats, rig, settings=default)
            t_default = time.perf_counter() - t0
            b = ms.render(m, pats, rig, settings=dense)
        rel_rmse = ((a - b).square().mean().sqrt() / b.square().mean().sqrt()).item()
        worst = ((a - b).abs().max() / torch.quantile(b.flatten()[:: max(1, b.numel() // 100000)], 0.99)).item()
        rows.append({"roughness": r, "rel_rmse_vs_4x": rel_rmse, "max_err_vs_p99": worst,
                     "seconds_default": t_default})

    lines = [
        f"Reference renderer (`{default}`) on {platform.processor() or platform.machine()}, "
        f"{torch.get_num_threads()} threads, torch {torch.__version__}.",
        "",
        f"Time for one {args.time_resolution}x{args.time_resolution} material under 5 patterns: "
        f"**{seconds:.1f} s**.",
        "",
        f"Error of the default settings against the 4x denser rule ({dense.cell_order}^2 points per cell, "
        f"{dense.lobe_grid}^2 lobe points), {args.error_resolution}x{args.error_resolution} px, "
        "MonoGrad + 5 random patterns:",
        "",
        "| roughness | rel. RMSE vs 4x | worst pixel / p99 | time at default (s) |",
        "|---:|---:|---:|---:|",
    ]
    lines += [f"| {x['roughness']} | {x['rel_rmse_vs_4x']:.2e} | {x['max_err_vs_p99']:.2e} | "
              f"{x['seconds_default']:.2f} |" for x in rows]
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.quick:
        write_report(args.out, "reference_accuracy", "Reference renderer accuracy", "reference_accuracy.py",
                     text, rows)


if __name__ == "__main__":
    main()
