"""Speed/accuracy trade of the renderers against the reference: LTC (exact, prefiltered), Mitsuba.

    .venv/bin/python benchmarks/render_tradeoff.py            # writes docs/benchmarks/render_tradeoff.*
    .venv/bin/python benchmarks/render_tradeoff.py --quick    # smoke run, nothing written

Materials: the bundled example's normal and diffuse maps with constant roughness r and ks = 0.3,
for r in {0.01, 0.05, 0.1, 0.3, 0.6, 1.0}, plus a near-grazing case (r = 0.3 with every normal
tilted 70 degrees away from the camera's azimuth). Patterns: MonoGrad, 5 random, 4 step edges.
Error: relative RMSE of each method's images against the reference renderer (default settings) at
``--error-size``; time: one material under 5 patterns at ``--time-size`` on this machine's CPU.
Prints a table, writes CSV + markdown, and a plot of error vs. time (one curve per method).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.cli import _resize_svbrdf
from mitsvbrdf.patterns import monograd, random, step_edges
from report import write_report

ROOT = Path(__file__).resolve().parent.parent
SPPS = (1, 4, 16, 64, 256)


def material(size: int, roughness: float, tilt_deg: float | None = None) -> ms.SVBRDF:
    base = _resize_svbrdf(ms.SVBRDF.load(ROOT / "examples" / "materials" / "artificial_0.png"), size)
    normal = base.normal
    if tilt_deg is not None:
        t = math.radians(tilt_deg)
        normal = torch.tensor([-math.sin(t), 0.0, math.cos(t)]).view(1, 3, 1, 1).expand_as(normal).contiguous()
    return ms.SVBRDF(normal=normal, diffuse=base.diffuse, roughness=torch.full_like(base.roughness, roughness),
                     specular=torch.full_like(base.specular, 0.3))


TILTS = (0.0, 10.0, 30.0, 60.0, 75.0)
BIAS_ROUGHNESS = (0.01, 0.03, 0.1, 0.3, 0.6, 1.0)


def tilted_normal(rig: ms.Rig, tilt_deg: float) -> tuple[float, float, float]:
    """Unit normal tilted ``tilt_deg`` away from the LCD's azimuth (75 degrees: the LCD crosses the
    horizon of the normal)."""
    lcd = rig.lcd_corners.mean(0)
    az = math.atan2(float(lcd[1]), float(lcd[0])) + math.pi
    t = math.radians(tilt_deg)
    return (math.sin(t) * math.cos(az), math.sin(t) * math.sin(az), math.cos(t))


def uniform_lcd_bias(rig: ms.Rig, size: int = 8) -> list[dict]:
    """LTC-exact specular lobe under one uniformly lit LCD vs the reference: relative RMSE per
    (tilt, roughness), and the reference's mean radiance (to tell large errors of tiny signals)."""
    rows = []
    p = torch.ones(1, 3, *rig.lcd_cells)
    for tilt in TILTS:
        row = {"tilt_deg": tilt}
        for r in BIAS_ROUGHNESS:
            m = ms.SVBRDF.constant(normal=tilted_normal(rig, tilt), diffuse=0.5, roughness=r, specular=0.5, size=size)
            ref = ms.render(m, p, rig, lobes="specular")
            ltc = ms.render(m, p, rig, method="ltc", lobes="specular")
            row[f"r={r}"] = round(((ltc - ref).square().mean().sqrt() / ref.square().mean().sqrt()).item(), 5)
            row[f"ref_mean r={r}"] = float(f"{ref.mean().item():.3g}")
        rows.append(row)
    return rows


def methods():
    """(name, render function(svbrdf, patterns, rig, seed)) for every method of the study."""
    out = [("ltc-exact", lambda m, p, rig, s: ms.render(m, p, rig, method="ltc", mode="exact")),
           ("ltc-prefiltered", lambda m, p, rig, s: ms.render(m, p, rig, method="ltc", mode="prefiltered"))]
    for spp in SPPS:
        out.append((f"mitsuba-{spp}spp",
                    lambda m, p, rig, s, spp=spp: ms.render(m, p, rig, method="mitsuba", spp=spp, seed=s)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--error-size", type=int, default=32)
    ap.add_argument("--time-size", type=int, default=128)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    cases = [(r, None) for r in (0.01, 0.05, 0.1, 0.3, 0.6, 1.0)] + [(0.3, 70.0)]
    if args.quick:
        args.error_size, args.time_size, cases = 16, 32, [(0.05, None), (0.6, None)]
    rig = ms.Rig.from_scene()
    pats = torch.cat([monograd(), random(n=5, seed=0), step_edges(n=4)])

    rows = []
    with torch.no_grad():
        refs = {}
        for r, tilt in cases:
            m = material(args.error_size, r, tilt)
            refs[(r, tilt)] = (m, ms.render(m, pats, rig))
        for name, fn in methods():  # time: one material under 5 patterns
            m = material(args.time_size, 0.3)
            fn(m, pats[:5], rig, 0)  # warm-up / compile
            t0 = time.perf_counter()
            fn(m, pats[:5], rig, 1)
            seconds = time.perf_counter() - t0
            errs = {}
            for (r, tilt), (m, ref) in refs.items():
                img = fn(m, pats, rig, 2)
                errs[(r, tilt)] = ((img - ref).square().mean().sqrt() / ref.square().mean().sqrt()).item()
            row = {"method": name, "seconds_per_material_5_patterns": round(seconds, 4)}
            row.update({f"r={r}" + (f",tilt={tilt:g}" if tilt else ""): round(e, 5) for (r, tilt), e in errs.items()})
            rows.append(row)
            print(row, flush=True)

    keys = [k for k in rows[0] if k.startswith("r=")]
    lines = [f"Relative RMSE against the reference renderer ({args.error_size}x{args.error_size} px, MonoGrad + "
             f"5 random + 4 step-edge patterns, ks = 0.3, the example's normal map; 'tilt=70' replaces it by normals "
             f"tilted 70 degrees, near-grazing views) and CPU time for one {args.time_size}x{args.time_size} material "
             f"under 5 patterns ({torch.get_num_threads()} threads).", "",
             "| method | time (s) | " + " | ".join(keys) + " |", "|---|---:|" + "---:|" * len(keys)]
    lines += [f"| {r['method']} | {r['seconds_per_material_5_patterns']} | " +
              " | ".join(f"{r[k]:.4f}" for k in keys) + " |" for r in rows]
    ltc = {r["method"]: r for r in rows}
    worst = {k: max(ltc["ltc-exact"][k], ltc["ltc-prefiltered"][k]) for k in keys}
    fails = [f"{k} ({worst[k]:.1%})" for k in keys if worst[k] > 0.05]
    lines += ["", "LTC errors above 5% (worse of its two modes): " + (", ".join(fails) if fails else "none") + "."]

    bias = uniform_lcd_bias(rig, size=8 if not args.quick else 4)
    rkeys = [f"r={r}" for r in BIAS_ROUGHNESS]
    lines += ["", "## One uniformly lit LCD: bias of the LTC specular lobe", "",
              "LTC-exact, specular lobe only, 8x8 px, flat material with every normal tilted away from the LCD's "
              "azimuth (75 degrees: the LCD crosses the normal's horizon). Relative RMSE against the reference; in "
              "brackets the reference's mean radiance (the LCD at drive 1 has radiance 1), so that a large relative "
              "error of a vanishing signal can be told from a real one.", "",
              "| tilt (deg) | " + " | ".join(rkeys) + " |", "|---:|" + "---:|" * len(rkeys)]
    lines += [f"| {b['tilt_deg']:g} | " + " | ".join(f"{b[k]:.4f} ({b['ref_mean ' + k]:.2g})" for k in rkeys) + " |"
              for b in bias]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    write_report(args.out, "render_tradeoff", "Renderer speed/accuracy trade", "render_tradeoff.py", text + "\n"
                 "![error vs time](render_tradeoff.png)\n", rows)
    write_report(args.out, "render_tradeoff_uniform_lcd", "LTC bias under one uniform LCD", "render_tradeoff.py",
                 "See render_tradeoff.md.\n", bias)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    # median over materials: one grazing outlier would otherwise hide the typical error
    mean_err = {r["method"]: float(torch.tensor([r[k] for k in keys]).median()) for r in rows}
    secs = {r["method"]: r["seconds_per_material_5_patterns"] for r in rows}
    mi_names = [n for n in secs if n.startswith("mitsuba")]
    ax.plot([secs[n] for n in mi_names], [mean_err[n] for n in mi_names], "o-", label="Mitsuba (1..256 spp)")
    for n, marker in (("ltc-exact", "s"), ("ltc-prefiltered", "^")):
        ax.plot([secs[n]], [mean_err[n]], marker, markersize=9, label=n)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(f"CPU seconds per {args.time_size}x{args.time_size} material, 5 patterns")
    ax.set_ylabel("relative RMSE vs reference (median over materials)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "render_tradeoff.png", dpi=120)


if __name__ == "__main__":
    main()
