"""Do the predicted patterns differ between very different materials? One figure, three archetypes.

    .venv/bin/python benchmarks/pattern_gallery.py [--networks mitsvbrdf/weights/networks.pt]

Three materials at ``--size`` px, each of one kind the method must tell apart:

* **metal**: flat, black diffuse, bright gold-coloured specular (0.95, 0.75, 0.35), roughness 0.15;
* **rough dielectric**: flat, diffuse (0.55, 0.35, 0.25), specular 0.04, roughness 0.85;
* **bumpy**: a field of round bumps (slopes up to about 40 degrees) of grey diffuse 0.4,
  specular 0.08, roughness 0.35.

Each goes through the acquisition layer step by step (L_0 captured with Mitsuba at ``--spp``,
the initializer's estimate, L_pdf, G_l's four patterns). The figure shows, per material, I_0,
L_pdf and L_1..L_4; the table gives the RMS distance between the pattern sets of each pair
(drive values in [0, 1]) beside the RMS spread of each set's own four patterns, so a reader can
tell "differs between materials" from "differs between the four patterns of one material".
A second table sets the initializer's estimate of each material (what L_pdf is computed from)
beside the truth. Writes docs/benchmarks/pattern_gallery.md (+ CSV, PNG).

``--lpdf-from ground_truth`` computes L_pdf from each material's true normals and roughness
instead of the initializer's estimate (on the networks' working grid), the patterns G_l would
predict behind a perfect initializer: it tells whether alike patterns are the initializer's doing
or G_l's. Writes pattern_gallery_gt-lpdf.md (+ CSV, PNG).
"""

from __future__ import annotations

import argparse
import itertools
import math
from dataclasses import replace
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, load_adaptive, predict, rendered_capture
from mitsvbrdf.resolution import prediction_input, working_grid
from mitsvbrdf.viewing import tonemap
from report import write_report

ROOT = Path(__file__).resolve().parent.parent


def bumps(size: int, count: int = 6, height: float = 0.27) -> torch.Tensor:
    """(3, H, W) unit normals of a height field of count x count round bumps h = height cos^2."""
    t = (torch.arange(size) + 0.5) / size
    y, x = torch.meshgrid(t, t, indexing="ij")
    phase_x, phase_y = math.pi * count * x, math.pi * count * y
    # h = height * sin^2(px) sin^2(py) per cell; slopes from its derivative (height in cell units)
    dh_dx = height * math.pi * count * torch.sin(2 * phase_x) * torch.sin(phase_y) ** 2 / count
    dh_dy = height * math.pi * count * torch.sin(2 * phase_y) * torch.sin(phase_x) ** 2 / count
    n = torch.stack([-dh_dx, -dh_dy, torch.ones_like(dh_dx)])
    return n / n.norm(dim=0, keepdim=True)


def archetypes(size: int) -> dict[str, ms.SVBRDF]:
    metal = ms.SVBRDF.constant(diffuse=0.0, specular=(0.95, 0.75, 0.35), roughness=0.15, size=size)
    dielectric = ms.SVBRDF.constant(diffuse=(0.55, 0.35, 0.25), specular=0.04, roughness=0.85, size=size)
    flat = ms.SVBRDF.constant(diffuse=0.4, specular=0.08, roughness=0.35, size=size)
    bumpy = ms.SVBRDF(bumps(size)[None], flat.diffuse, flat.roughness, flat.specular)
    return {"metal": metal, "rough dielectric": dielectric, "bumpy": bumpy}


SUMMARY = ("roughness", "normal tilt", "specular")


def summary(m: ms.SVBRDF) -> dict[str, float]:
    """Mean roughness, RMS normal tilt (|n_xy|, the sine of the angle from +z) and mean specular
    albedo of one material."""
    n = m.normal[0]
    return {"roughness": float(m.roughness.mean()), "normal tilt": float(n[:2].square().sum(0).mean().sqrt()),
            "specular": float(m.specular.mean())}


def rms(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).square().mean().sqrt())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks", type=Path, default=DEFAULT_NETWORKS)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--lpdf-from", choices=("initializer", "ground_truth"), default="initializer",
                    help="L_pdf from the initializer's estimate (the method) or from the true maps")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    rig = ms.Rig.from_scene()
    acq = load_adaptive(args.networks, rig)
    acq.check_resolution(args.size, "--size")
    truth = args.lpdf_from == "ground_truth"
    stem = "pattern_gallery_gt-lpdf" if truth else "pattern_gallery"
    mats = archetypes(args.size)
    shown, seen = {}, {}
    for name, m in mats.items():
        capture = rendered_capture(m, rig, method="mitsuba", spp=args.spp, seed=0)
        i0 = capture(acq.l0[None, None])[:, 0]
        patterns, lpdf, estimate = acq.predict_patterns(i0)
        if truth:  # G_l behind a perfect initializer: L_pdf from the true maps on the working grid
            x = prediction_input(i0, acq.settings.resolution, acq.transfer)
            with torch.no_grad():
                p = predict(acq.initializer, acq.lighting, x, rig, replace(acq.settings, lpdf_from="ground_truth"),
                            l0=acq.l0, ground_truth=m.resized(working_grid(tuple(i0.shape[-2:]), acq.settings.resolution)))
            patterns, lpdf = p.patterns, p.lpdf
        shown[name] = (i0[0], lpdf[0, 0], patterns[0])
        seen[name] = {"material": name, **{f"{k} {which}": round(v, 4) for which, mm in (("est.", estimate), ("true", m))
                                         for k, v in summary(mm).items()}}
    rows = []
    for a, b in itertools.combinations(shown, 2):
        rows.append({"pair": f"{a} vs {b}", "rms_between": round(rms(shown[a][2], shown[b][2]), 4)})
    for name, (_, _, p) in shown.items():
        spread = sum(rms(p[i], p[j]) for i, j in itertools.combinations(range(4), 2)) / 6
        rows.append({"pair": f"{name}: its own 4 patterns (mean pairwise)", "rms_between": round(spread, 4)})
    net = args.networks.relative_to(ROOT) if args.networks.is_relative_to(ROOT) else args.networks
    lpdf_opt = " --lpdf-from ground_truth" if truth else ""
    text = (f"Command: `benchmarks/pattern_gallery.py --networks {net} --size {args.size} --spp {args.spp}{lpdf_opt}`\n\n"
            + ("L_pdf from each material's true normals and roughness, not the initializer's estimate: the "
               "patterns G_l predicts behind a perfect initializer.\n\n" if truth else "") +
            "RMS distance of drive values (in [0, 1]) between the 4 predicted patterns of two materials, "
            "and within one material's set.\n\n| pair | RMS distance |\n|---|---:|\n" +
            "\n".join(f"| {r['pair']} | {r['rms_between']} |" for r in rows) + f"\n\n![patterns]({stem}.png)\n\n"
            "L_pdf, and through it the patterns, comes from the initializer's estimate from I_0: its mean "
            "roughness, RMS normal tilt (sin of the angle from +z) and mean specular albedo beside the truth.\n\n"
            "| material | " + " | ".join(f"{k} {w}" for k in SUMMARY for w in ("est.", "true")) + " |\n|---|"
            + "---:|" * (2 * len(SUMMARY)) + "\n"
            + "\n".join(f"| {r['material']} | " + " | ".join(f"{r[f'{k} {w}']:.3f}" for k in SUMMARY for w in ("est.", "true"))
                         + " |" for r in seen.values()) + "\n")
    print(text)
    write_report(args.out, stem, "Predicted patterns of a metal, a rough dielectric and a bumpy material",
                 "pattern_gallery.py", text, rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(shown), 6, figsize=(9, 1.6 * len(shown)))
    for r, (name, (i0, lpdf, p)) in enumerate(shown.items()):
        axes[r, 0].imshow(tonemap(i0).permute(1, 2, 0).numpy())
        axes[r, 0].set_ylabel(name, fontsize=8)
        axes[r, 1].imshow(lpdf.numpy(), cmap="magma")
        for j in range(4):
            axes[r, j + 2].imshow(p[j].permute(1, 2, 0).clamp(0, 1).numpy())
    for j, title in enumerate(["I_0", "L_pdf", "L_1", "L_2", "L_3", "L_4"]):
        axes[0, j].set_title(title, fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(args.out / f"{stem}.png", dpi=100)


if __name__ == "__main__":
    main()
