"""CPU latency of the acquisition's learned steps for one 256 x 256 material: pattern prediction
(initializer + L_pdf + G_l) and reconstruction (separation + G_sc), with the shipped networks.

    .venv/bin/python benchmarks/pipeline_latency.py [--networks mitsvbrdf/weights/networks.pt]

The captures are rendered once (Mitsuba, 64 spp) and not timed; each step is timed as the median
of 5 runs after a warm-up run (which builds the separation's cached diffuse kernel). Writes
docs/benchmarks/pipeline_latency_cpu.md (+ CSV).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, initial_estimate, load_adaptive, maps_to_svbrdf
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.importance import importance
from report import median_seconds, write_report

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks", type=Path, default=DEFAULT_NETWORKS)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    rig = ms.Rig.from_scene()
    pipe = load_adaptive(args.networks, rig)
    gt = ms.SVBRDF.load(DEFAULT_MATERIAL).resized(args.size)
    with torch.no_grad():
        i0 = ms.render(gt, pipe.l0[None], rig, method="mitsuba", spp=64, seed=1)[:, 0]
        adaptive, _, _ = pipe.predict_patterns(i0)
        patterns = pipe.all_patterns(adaptive)
        images = ms.render(gt, patterns, rig, method="mitsuba", spp=64, seed=2)
    predict = median_seconds(lambda: pipe.predict_patterns(i0))
    reconstruct = median_seconds(lambda: pipe.reconstruct(images, patterns))
    rows = [{"step": "pattern prediction (initializer + L_pdf + G_l)", "seconds": round(predict, 3)},
            {"step": "reconstruction (separation + G_sc)", "seconds": round(reconstruct, 3)},
            {"step": "total", "seconds": round(predict + reconstruct, 3)}]
    grid = pipe.settings.resolution
    text = (f"One {args.size}x{args.size} material, networks `{args.networks.name}` "
            f"({sum(p.numel() for p in pipe.parameters()):,} parameters, trained at {grid or 'an unrecorded'} px; "
            f"resolution transfer {pipe.transfer!r}), CPU with {torch.get_num_threads()} "
            "threads; median of 5 runs after a warm-up.\n\n| step | seconds |\n|---|---:|\n" +
            "\n".join(f"| {r['step']} | {r['seconds']} |" for r in rows) + "\n")
    stride_rows = lpdf_stride_tradeoff(pipe, i0, rig)
    text += ("\n## L_pdf texel stride: cost and error\n\nL_pdf of the initializer's estimate of the same "
             f"material on its own {args.size} px grid (the \"native\" transfer; the default predicts on the "
             "training grid), computed on every s-th texel; error against s = 1 (relative RMSE of the [0, 1] L_pdf), "
             "and the RMS change of the 4 predicted patterns (drive values). The pipeline's default is "
             f"{pipe.settings.lpdf_stride}.\n\n| stride | L_pdf seconds | L_pdf rel. RMSE | pattern RMS change |\n"
             "|---:|---:|---:|---:|\n" +
             "\n".join(f"| {r['stride']} | {r['seconds']} | {r['lpdf_rel_rmse']} | {r['pattern_rms_change']} |"
                       for r in stride_rows) + "\n")
    print(text)
    write_report(args.out, "pipeline_latency_cpu", "Acquisition latency on CPU", "pipeline_latency.py", text, rows)


def lpdf_stride_tradeoff(pipe, i0: torch.Tensor, rig, strides=(1, 2, 4, 8, 16)) -> list[dict]:
    """Seconds and error of L_pdf per texel stride, and the change of the patterns G_l predicts from it."""
    with torch.no_grad():
        est = maps_to_svbrdf(initial_estimate(pipe.initializer, i0, pipe.l0, rig))
        ref = importance(est.normal, est.roughness, rig, texel_stride=1)
        ref_pats = pipe.lighting(i0, ref).patterns
        rows = []
        for s in strides:
            lp = ref if s == 1 else importance(est.normal, est.roughness, rig, texel_stride=s)
            secs = median_seconds(lambda: importance(est.normal, est.roughness, rig, texel_stride=s), repeats=3)
            pats = pipe.lighting(i0, lp).patterns
            rows.append({"stride": s, "seconds": round(secs, 3),
                         "lpdf_rel_rmse": round(float((lp - ref).square().mean().sqrt() / ref.square().mean().sqrt()), 4),
                         "pattern_rms_change": round(float((pats - ref_pats).square().mean().sqrt()), 4)})
    return rows


if __name__ == "__main__":
    main()
