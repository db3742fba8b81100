"""Resolution transfer: networks trained at R px reconstructing finer captures, per transfer mode.

    .venv/bin/python benchmarks/resolution_transfer.py [--networks mitsvbrdf/weights/networks.pt]
        [--sizes 128,256] [--n 32] [--spp 32]

Sets: the demo's bundled material, the 4 sample materials ($MITSVBRDF_SAMPLES) and ``--n``
held-out procedural materials (seeds from 1 000 000, never trained on). At each size every
material's acquisition is simulated (Mitsuba at ``--spp``, seed 0) and reconstructed in each
transfer mode of :mod:`mitsvbrdf.resolution` (native, coarse, fused, pyramid; each mode predicts its own
patterns, as it would at the bench). The row "at R px" is the same materials resized to the
networks' own training grid and reconstructed there, scored at R: what the networks do where
they trained.

Per set, size and mode: the mean RMSE of each encoded map and their average, the flat-normal
level (predicting n = +z) and seconds per material; then the paired per-material difference of
the average and normal RMSE of every other mode against native (mean +- standard error), and of
"fused" against "fused-area" (the roughness's low band from the texel phases against the area
average) for the average and the roughness RMSE. The
figure shows the demo material's normal maps at the largest size: ground truth, then each mode. Writes docs/benchmarks/resolution_transfer.md (+ CSV, PNG).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf import imageio
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, load_adaptive
from mitsvbrdf.evaluation import paired_difference
from mitsvbrdf.metrics import flat_normal_rmse, map_rmse
from mitsvbrdf.resolution import TRANSFER_MODES
from mitsvbrdf.viewing import pattern_strip
from report import goal_sets, write_report

ROOT = Path(__file__).resolve().parent.parent
MAPS = ("normal", "diffuse", "roughness", "specular", "average")


def score(acquisitions: dict, gt: ms.SVBRDF, spp: int) -> tuple[dict[str, dict[str, float]], dict[str, ms.SVBRDF]]:
    """({mode: {map: RMSE, "seconds": s}}, {mode: reconstruction}) for one material, every mode
    from its own acquisition."""
    out, recs = {}, {}
    for mode, acq in acquisitions.items():
        t = time.perf_counter()
        recs[mode] = acq.simulate(gt, spp=spp, seed=0).svbrdf
        s = time.perf_counter() - t
        out[mode] = {k: float(v[0]) for k, v in map_rmse(recs[mode], gt).items()} | {"seconds": s}
    return out, recs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks", type=Path, default=DEFAULT_NETWORKS)
    ap.add_argument("--sizes", default="128,256", help="capture sizes in px, comma-separated")
    ap.add_argument("--n", type=int, default=32, help="procedural materials")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    rig = ms.Rig.from_scene()
    acqs = {mode: load_adaptive(args.networks, rig, transfer=mode) for mode in TRANSFER_MODES}
    trained = acqs["fused"].settings.resolution
    if trained is None:
        raise SystemExit(f"{args.networks} does not record its training resolution; nothing to transfer")
    sizes = [int(s) for s in args.sizes.split(",")]
    for s in sizes:
        acqs["fused"].check_resolution(s, "--sizes")
    acqs["native"].simulate(ms.SVBRDF.constant(size=trained), spp=1)  # kernels compiled outside the timings
    per_material: list[dict] = []  # one row per set, size, mode and material
    figure = None
    for size in sizes:
        for set_name, mats in goal_sets(size, args.n).items():
            for k, gt in enumerate(mats):
                name = gt.name or f"{set_name}:{k}"
                flat = float(flat_normal_rmse(gt)[0])
                res, recs = score(acqs, gt, args.spp)
                if set_name == "demo material" and size == max(sizes):
                    figure = (gt, recs)
                if size > trained:  # the networks on their own grid: the material resized to R, scored there
                    small = gt.resized(trained)
                    res[f"at {trained} px"] = score({"native": acqs["native"]}, small, args.spp)[0]["native"]
                    res[f"at {trained} px"]["flat"] = float(flat_normal_rmse(small)[0])
                for mode, r in res.items():
                    per_material.append({"set": set_name, "size": size, "mode": mode, "material": name,
                                         "flat": r.pop("flat", flat), **r})
                print(f"{size} px {set_name} {name}: " + ", ".join(f"{m} {r['average']:.4f}" for m, r in res.items()),
                      flush=True)
    rows, lines = [], []
    modes = list(TRANSFER_MODES) + [f"at {trained} px"]
    lines += ["| set | px | mode | " + " | ".join(MAPS) + " | flat normal | s / material |",
              "|---|---:|---|" + "---:|" * (len(MAPS) + 2)]
    for size in sizes:
        for set_name in dict.fromkeys(r["set"] for r in per_material):
            sel = [r for r in per_material if r["set"] == set_name and r["size"] == size]
            for mode in modes:
                m = [r for r in sel if r["mode"] == mode]
                if not m:
                    continue
                row = {"set": set_name, "size": size if not mode.startswith("at ") else trained, "mode": mode,
                       "materials": len(m), **{k: round(sum(r[k] for r in m) / len(m), 5) for k in MAPS},
                       "flat_normal": round(sum(r["flat"] for r in m) / len(m), 5),
                       "seconds": round(sum(r["seconds"] for r in m) / len(m), 2)}
                rows.append(row)
                shown_size = f"{size} -> {trained}" if mode.startswith("at ") else str(size)
                lines.append(f"| {set_name} | {shown_size} | {mode} | " + " | ".join(f"{row[k]:.4f}" for k in MAPS) +
                             f" | {row['flat_normal']:.4f} | {row['seconds']} |")
    diff = ["| set | px | mode | average vs native | normal vs native |", "|---|---:|---|---:|---:|"]
    for size in sizes:
        for set_name in dict.fromkeys(r["set"] for r in per_material):
            sel = [r for r in per_material if r["set"] == set_name and r["size"] == size]
            for mode in TRANSFER_MODES[1:]:
                avg, nrm = (paired_difference(sel, "native", mode, k, "mode") for k in ("average", "normal"))
                diff.append(f"| {set_name} | {size} | {mode} | {avg} | {nrm} |")
    phases = ["| set | px | average, fused - fused-area | roughness, fused - fused-area |", "|---|---:|---:|---:|"]
    for size in sizes:
        for set_name in dict.fromkeys(r["set"] for r in per_material):
            sel = [r for r in per_material if r["set"] == set_name and r["size"] == size]
            avg, rough = (paired_difference(sel, "fused-area", "fused", k, "mode") for k in ("average", "roughness"))
            phases.append(f"| {set_name} | {size} | {avg} | {rough} |")
    net = args.networks.relative_to(ROOT) if args.networks.is_relative_to(ROOT) else args.networks
    text = (f"Command: `benchmarks/resolution_transfer.py --networks {net} --sizes {args.sizes} --n {args.n} "
            f"--spp {args.spp}`\n\nNetworks trained at {trained} px. Mean map RMSE (encoded maps) per set, size "
            "and transfer mode (`mitsvbrdf.resolution`); \"at R px\" is the same materials resized to the training "
            "grid and reconstructed there. Seconds per material: simulated capture and reconstruction; the first "
            "row of each size (the demo material, native) includes Dr.Jit's kernel compilation for that size.\n\n" +
            "\n".join(lines) + "\n\nPaired per-material differences against native (mean +- standard error; "
            "negative: better than native):\n\n" + "\n".join(diff) +
            "\n\nThe roughness's low band from the mean of the runs over the texel phases (\"fused\", the "
            "default) against the area-averaged capture (\"fused-area\"), paired per material (negative: the "
            "phases better):\n\n" + "\n".join(phases) +
            "\n\nNormal maps of the demo material at the largest size (encoded: ground truth, then "
            f"{', '.join(TRANSFER_MODES)}):\n\n![normals](resolution_transfer.png)\n")
    print(text)
    write_report(args.out, "resolution_transfer", "Resolution transfer: reconstructing finer captures than the "
                 "networks trained on", "resolution_transfer.py", text, rows)
    gt, recs = figure
    tiles = [gt.encoded()[0, :3]] + [recs[m].encoded()[0, :3] for m in TRANSFER_MODES]
    imageio.write_png(args.out / "resolution_transfer.png", pattern_strip(torch.stack(tiles)))


if __name__ == "__main__":
    main()
