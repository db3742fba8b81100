"""Adaptivity of the trained lighting predictor: do predicted patterns differ between materials?

    .venv/bin/python benchmarks/adaptivity.py [--networks runs/stage1-small/networks.pt] [--n 32]

For n held-out procedural materials (seeds from TEST_SEED_BASE, never used in training) the
trained L_0 + initializer + G_l predict the 4 adaptive patterns (I_0 rendered with Mitsuba).
Reported: the mean pairwise RMS distance between the patterns of different materials, against
the RMS distance between the patterns of two randomly initialised G_l (different seeds) for the
same material (how far apart patterns are by chance), and the pairwise distance across
materials of an untrained G_l. Writes docs/benchmarks/adaptivity.md (+ CSV) and a PNG of the
patterns of 8 materials.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.data.procedural import generate
from mitsvbrdf.importance import importance
from mitsvbrdf.nets import LightingPredictor, network_from_record
from mitsvbrdf.acquisition import maps_to_svbrdf
from mitsvbrdf.viewing import tonemap
from mitsvbrdf.training.config import TEST_SEED_BASE
from report import write_report

ROOT = Path(__file__).resolve().parent.parent


def pairwise_rms(p: torch.Tensor) -> float:
    """Mean RMS distance between the pattern sets (N, 4, 3, h, w) of all pairs of materials."""
    flat = p.flatten(1)
    d = torch.cdist(flat, flat) / flat.shape[1] ** 0.5
    n = p.shape[0]
    return float(d.sum() / (n * (n - 1)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks", type=Path, default=ROOT / "runs" / "stage1-small" / "networks.pt")
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--size", type=int, default=32)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    torch.manual_seed(0)
    rig = ms.Rig.from_scene()
    if not args.networks.exists():
        raise SystemExit(f"{args.networks} does not exist: train init-small and stage1-small first (docs/training.md)")
    recs = torch.load(args.networks, weights_only=True)
    l0, init, lighting = (network_from_record(recs[k], k).eval() for k in ("l0", "initializer", "lighting"))
    mats = generate(args.n, size=args.size, seed=TEST_SEED_BASE)
    with torch.no_grad():
        i0 = ms.render(mats, l0(), rig, method="mitsuba", spp=16, seed=1)[:, 0]
        est = maps_to_svbrdf(init(i0))
        lpdf = importance(est.normal, est.roughness, rig, texel_stride=4)
        trained = lighting(i0, lpdf).patterns
        fresh = []
        for s in (1, 2):
            torch.manual_seed(s)
            fresh.append(LightingPredictor(**lighting.config)(i0, lpdf).patterns)
    rows = [{"quantity": "trained G_l: mean pairwise RMS distance between materials' patterns",
             "value": round(pairwise_rms(trained), 5)},
            {"quantity": "two random initialisations of G_l: RMS distance for the same material",
             "value": round(float((fresh[0] - fresh[1]).flatten(1).square().mean(1).sqrt().mean()), 5)},
            {"quantity": "untrained G_l: mean pairwise RMS distance between materials' patterns",
             "value": round(pairwise_rms(fresh[0]), 5)}]
    text = (f"{args.n} held-out procedural materials ({args.size} px, seeds from {TEST_SEED_BASE}), networks "
            f"`{args.networks.relative_to(ROOT) if args.networks.is_relative_to(ROOT) else args.networks}`.\n\n"
            "| quantity | value |\n|---|---:|\n" + "\n".join(f"| {r['quantity']} | {r['value']} |" for r in rows)
            + "\n\n![patterns](adaptivity.png)\n")
    print(text)
    write_report(args.out, "adaptivity", "Adaptivity of the predicted patterns", "adaptivity.py", text, rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = min(8, args.n)
    fig, axes = plt.subplots(k, 5, figsize=(6, 1.25 * k))
    for i in range(k):
        axes[i, 0].imshow(tonemap(i0[i]).permute(1, 2, 0).numpy())
        for j in range(4):
            axes[i, j + 1].imshow(trained[i, j].permute(1, 2, 0).numpy())
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].set_title("I_0", fontsize=8)
    for j in range(4):
        axes[0, j + 1].set_title(f"L_{j + 1}", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / "adaptivity.png", dpi=100)


if __name__ == "__main__":
    main()
