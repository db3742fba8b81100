"""Roughness read from a capture finer than the training grid: the area average's bias and its remedies.

    .venv/bin/python benchmarks/roughness_bias.py [--networks mitsvbrdf/weights/networks.pt]
        [--size 256] [--n 16] [--spp 32] [--seed 3000000]

Networks trained on R x R materials see each texel as one normal; a coarse texel of a finer
material mixes the reflections of differently tilted sub-texels, which widens a glossy highlight as
a rougher surface would (Toksvig's effect). This script measures what that does to the roughness
the networks read, on ``--n`` procedural materials made at ``--size`` px from ``--seed`` (by default
outside the held-out test seeds, 1 000 000 on, and the training stream's, so that choosing the
default transfer here does not tune it on the test set). Each material is captured (Mitsuba at
``--spp``, seed 0) and reconstructed:

* ``at R px``: the material resized to R and reconstructed there (the networks' own bias);
* ``fused-area``: the low band of every map from the capture area-averaged to R;
* ``fused`` (the default): the roughness's low band from the capture sampled at the R texel centres
  (mitsvbrdf.resolution);
* ``toksvig``: "fused-area" with its low band's alpha = r^2 corrected by the slope variance
  s^2 of its own reconstructed normals within each R texel, alpha^2 -> max(alpha^2 - s^2, 0)
  (Toksvig's widening inverted; rejected).

Per material class (smooth: mean roughness below 0.3; rough: the others; all) the mean signed
roughness error (bias) and the roughness and average map RMSE of each variant; the mean slope
variance of the ground-truth relief within the R texels says how much finer relief each class has.
Writes docs/benchmarks/roughness_bias.md (+ CSV).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, load_adaptive
from mitsvbrdf.data import generate
from mitsvbrdf.metrics import map_rmse
from mitsvbrdf.svbrdf import resample_texels
from report import write_report

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = ("at R px", "fused-area", "fused", "toksvig")
SMOOTH = 0.3  # mean roughness below which a material counts as smooth


def slope_variance(normal: torch.Tensor, grid: tuple[int, int]) -> torch.Tensor:
    """(B, 1, h, w): the variance of the slopes (n_x / n_z, n_y / n_z) of ``normal`` (B, 3, H, W)
    within each texel of the coarser ``grid``, summed over both axes."""
    nz = normal[:, 2:3].clamp_min(1e-3)
    var = 0
    for s in (normal[:, 0:1] / nz, normal[:, 1:2] / nz):
        var = var + resample_texels(s * s, grid) - resample_texels(s, grid) ** 2
    return var.clamp_min(0)


def toksvig(rec: ms.SVBRDF, grid: tuple[int, int]) -> ms.SVBRDF:
    """``rec`` with the low band of its roughness narrowed by its own normals' slope variance."""
    full = tuple(rec.roughness.shape[-2:])
    low = resample_texels(rec.roughness, grid)
    narrowed = (low ** 4 - slope_variance(rec.normal, grid)).clamp_min(0) ** 0.25
    r = (rec.roughness + resample_texels(narrowed - low, full)).clamp(0, 1)
    return ms.SVBRDF(normal=rec.normal, diffuse=rec.diffuse, roughness=r, specular=rec.specular)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks", type=Path, default=DEFAULT_NETWORKS)
    ap.add_argument("--size", type=int, default=256, help="capture size in px")
    ap.add_argument("--n", type=int, default=16, help="procedural materials")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--seed", type=int, default=3_000_000, help="first procedural seed")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    rig = ms.Rig.from_scene()
    acqs = {mode: load_adaptive(args.networks, rig, transfer=mode) for mode in ("fused-area", "fused")}
    trained = acqs["fused"].settings.resolution
    if trained is None or trained >= args.size:
        raise SystemExit(f"{args.networks} trained at {trained} px: nothing to transfer to {args.size} px")
    grid = (trained, trained)
    mats = generate(args.n, size=args.size, seed=args.seed)
    per_material = []
    for i in range(args.n):
        gt = mats[i]
        small = gt.resized(trained)
        recs = {mode: acq.simulate(gt, spp=args.spp, seed=0).svbrdf for mode, acq in acqs.items()}
        recs["toksvig"] = toksvig(recs["fused-area"], grid)
        recs["at R px"] = acqs["fused"].simulate(small, spp=args.spp, seed=0).svbrdf
        row = {"material": i, "roughness": float(gt.roughness.mean()),
               "slope_var": float(slope_variance(gt.normal, grid).mean())}
        for v in VARIANTS:
            ref = small if v == "at R px" else gt
            e = map_rmse(recs[v], ref)
            row[f"{v} bias"] = float((recs[v].roughness - ref.roughness).mean())
            row[f"{v} roughness"] = float(e["roughness"][0])
            row[f"{v} average"] = float(e["average"][0])
        per_material.append(row)
        print(f"material {i}: roughness {row['roughness']:.3f}, slope variance {row['slope_var']:.4f}; " +
              ", ".join(f"{v} bias {row[f'{v} bias']:+.4f}" for v in VARIANTS), flush=True)
    classes = {"smooth": [r for r in per_material if r["roughness"] < SMOOTH],
               "rough": [r for r in per_material if r["roughness"] >= SMOOTH], "all": per_material}
    rows, lines = [], ["| materials | n | slope variance | variant | roughness bias | roughness RMSE | average RMSE |",
                       "|---|---:|---:|---|---:|---:|---:|"]
    for name, sel in classes.items():
        if not sel:
            continue
        sv = sum(r["slope_var"] for r in sel) / len(sel)
        for v in VARIANTS:
            m = {k: sum(r[f"{v} {k}"] for r in sel) / len(sel) for k in ("bias", "roughness", "average")}
            rows.append({"materials": name, "n": len(sel), "slope_var": round(sv, 5), "variant": v,
                         **{k: round(x, 5) for k, x in m.items()}})
            lines.append(f"| {name} | {len(sel)} | {sv:.4f} | {v} | {m['bias']:+.4f} | {m['roughness']:.4f} | "
                         f"{m['average']:.4f} |")
    net = args.networks.relative_to(ROOT) if args.networks.is_relative_to(ROOT) else args.networks
    text = (f"Command: `benchmarks/roughness_bias.py --networks {net} --size {args.size} --n {args.n} "
            f"--spp {args.spp} --seed {args.seed}`\n\nNetworks trained at {trained} px; {args.n} procedural "
            f"materials at {args.size} px from seed {args.seed}. Smooth: mean roughness below {SMOOTH}. Slope "
            f"variance: of the ground-truth normals within each {trained} px texel. Bias: mean signed error of "
            "the roughness map (\"at R px\": against the material resized to R). Variants: module docstring of "
            "`benchmarks/roughness_bias.py`.\n\n" + "\n".join(lines) + "\n")
    print(text)
    write_report(args.out, "roughness_bias", "Roughness read from a capture finer than the training grid",
                 "roughness_bias.py", text, rows)


if __name__ == "__main__":
    main()
