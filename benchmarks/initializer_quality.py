"""What the initializer recovers from I_0: its estimate's map RMSE beside a flat normal map's.

    .venv/bin/python benchmarks/initializer_quality.py [--networks A.pt [--networks B.pt ...]]

L_pdf (Eq. 2-3), and through it the four adaptive patterns, comes from the initializer's normal
and roughness estimate (``AdaptiveAcquisition.predict_patterns``). An initializer whose normal
map sits at the flat-normal level gives a bumpy material the L_pdf of a flat one of the same
roughness, so G_l cannot adapt the patterns to relief (the pattern gallery's "rough dielectric vs
bumpy" pair). For each export: I_0 under its L_0, rendered by the reference renderer, and the
initializer's estimate scored (map RMSE on encoded maps, as ``evaluate``) on ``--n`` held-out
procedural materials (``evaluate``'s seeds), the demo material and the sample materials
($MITSVBRDF_SAMPLES, when present), all at ``--size`` px (default: the export's training grid).
A second table asks whether the relief is in I_0 at all: how much of the image the normals
explain (against a flat normal map, and against the tilts reversed), under each export's L_0
and, for scale, under MonoGrad's gradients.
Writes docs/benchmarks/initializer_quality.md (+ CSV).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from statistics import median

import torch
from torch import Tensor

import mitsvbrdf as ms
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, load_adaptive
from mitsvbrdf.evaluation import load_materials
from mitsvbrdf.metrics import MAP_CHANNELS, flat_normal_rmse, map_rmse
from mitsvbrdf.patterns import monograd
from report import goal_sets, write_report

ROOT = Path(__file__).resolve().parent.parent


def shown(path: Path) -> str:
    """A path as the table shows it: relative to the checkout when inside it."""
    p = path.resolve()
    return str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else str(path)


@torch.no_grad()
def initial_estimate(acq, m: ms.SVBRDF) -> ms.SVBRDF:
    """The initializer's estimate of ``m`` from I_0 (reference renderer) under the export's L_0."""
    i0 = ms.render(m, acq.l0[None], acq.rig, method="reference")[:, 0]
    return acq.predict_patterns(i0)[2]


def relief_signal(m: ms.SVBRDF, patterns: Tensor, rig: ms.Rig) -> tuple[float, float]:
    """How much of the images of ``m`` under ``patterns`` (P, 3, h, w) its relief explains
    (reference renderer): RMS(I(n) - I(z)) / RMS(I(n)), z the flat normal map, and the same with
    the tilts reversed (n's x and y negated) in place of z. The second is the signal that tells a
    slope from its opposite, which a normal estimate needs beyond "there is relief here"."""
    maps = m.maps()
    flat, reversed_ = dict(maps), dict(maps)
    flat["normal"] = torch.zeros_like(maps["normal"])
    flat["normal"][..., 2, :, :] = 1
    reversed_["normal"] = maps["normal"] * torch.tensor([-1.0, -1.0, 1.0]).reshape(3, 1, 1)
    img = ms.render(m, patterns, rig, method="reference")
    rms = img.square().mean().sqrt()
    return tuple(float((img - ms.render(ms.SVBRDF(**other), patterns, rig, method="reference")).square().mean().sqrt()
                       / rms) for other in (flat, reversed_))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--networks", type=Path, action="append", help="exports to score (default: the shipped one)")
    ap.add_argument("--size", type=int, default=0, help="px (0: the first export's training grid)")
    ap.add_argument("--n", type=int, default=32, help="held-out procedural materials")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    exports = args.networks or [DEFAULT_NETWORKS]
    rig = ms.Rig.from_scene()
    acqs = {shown(p): load_adaptive(p, rig) for p in exports}
    size = args.size or next(iter(acqs.values())).settings.resolution or 64
    maps = list(MAP_CHANNELS)
    rows = []
    for set_name, mats in goal_sets(size, args.n).items():
        flat = sum(float(flat_normal_rmse(m)[0]) for m in mats) / len(mats)
        for export, acq in acqs.items():
            acq.check_resolution(size, "--size")
            scores = [map_rmse(initial_estimate(acq, m), m) for m in mats]
            row = {"set": set_name, "networks": export, "px": size}
            row.update({k: round(sum(float(s[k][0]) for s in scores) / len(scores), 4) for k in maps + ["average"]})
            row["flat normal"] = round(flat, 4)
            rows.append(row)
            print(row, flush=True)
    lines = [f"Command: `{shlex.join(['benchmarks/initializer_quality.py'] + sys.argv[1:])}`", "",
             f"The initializer's estimate from I_0 (reference renderer, the export's L_0) at {size} px: mean map RMSE "
             "(encoded maps) per set. A normal RMSE at the flat-normal level means the estimate, and the L_pdf "
             "computed from it, do not see the relief.", "",
             "| set | networks | " + " | ".join(maps) + " | average | flat normal |",
             "|---|---|" + "---:|" * (len(maps) + 2)]
    lines += [f"| {r['set']} | `{r['networks']}` | " + " | ".join(f"{r[k]:.4f}" for k in maps + ["average"])
              + f" | {r['flat normal']:.4f} |" for r in rows]
    # Is the relief in I_0 at all? The same measure under MonoGrad's four gradients for scale.
    procedural = load_materials("procedural", size, args.n)
    h, w = rig.lcd_cells
    lights = {f"L_0 of `{export}`": acq.l0[None] for export, acq in acqs.items()}
    lights["MonoGrad's 4 gradients"] = monograd(h, w)[1:]
    signal_rows = []
    for name, pats in lights.items():
        pairs = [relief_signal(m, pats.float(), rig) for m in procedural]
        signal_rows.append({"patterns": name, "flat": median(p[0] for p in pairs),
                            "reversed": median(p[1] for p in pairs)})
        print(signal_rows[-1], flush=True)
    lines += ["", f"The relief's share of the images themselves, median over the {args.n} procedural materials at "
              f"{size} px (reference renderer): RMS(I(n) - I(flat)) / RMS(I(n)), and the same against the "
              "normals with their tilts reversed (x, y negated), which is what tells a slope from its "
              "opposite. Where I_0 carries about as much of it as a gradient pattern, a flat estimate is the "
              "initializer's failure to read it, not its absence from I_0.", "",
              "| patterns | relief (against flat) | tilt direction (against reversed) |", "|---|---:|---:|"]
    lines += [f"| {r['patterns']} | {r['flat']:.4f} | {r['reversed']:.4f} |" for r in signal_rows]
    text = "\n".join(lines) + "\n"
    print(text)
    write_report(args.out, "initializer_quality", "The initializer's estimate", "initializer_quality.py", text, rows)


if __name__ == "__main__":
    main()
