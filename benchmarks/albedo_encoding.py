"""Albedo encoding of Deschaintre-format strips: do their render tiles match linear or sRGB albedos?

Run (the 4 development samples are 4-tile strips without their render tile; the tiles are the
matching flash images ``0.png .. 3.png`` of the samples' source folder, see the .md):

    .venv/bin/python benchmarks/albedo_encoding.py --renders DIR            # DIR/<i>.png for <i>_svbrdf.png
    .venv/bin/python benchmarks/albedo_encoding.py --maps DIR_OF_5_TILE_STRIPS   # tiles from the strips

For each material: fit one flash position (at the camera) and one global scale per hypothesis
(stored albedos rendered as linear values, both sRGB-decoded first, or kd only), tone each to sRGB and compare
with the tile on its unsaturated pixels (:mod:`mitsvbrdf.data.encoding`). Writes
``albedo_encoding.md`` / ``.csv`` and ``albedo_encoding.png`` (per material: the toned render under
each hypothesis | their signed errors against the tile; ``--with-tiles`` adds the tile itself, for
looking at locally) into docs/benchmarks/.
"""

from __future__ import annotations

import argparse
import re
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from mitsvbrdf import SVBRDF
from mitsvbrdf.data import encoding
from mitsvbrdf.imageio import read_image
from report import SAMPLES, write_report

ROOT = Path(__file__).resolve().parent.parent
H = encoding.HYPOTHESES
#: A material decides only when the runner-up's RMSE exceeds the best one's by this fraction: about
#: 5x the spread of the best RMSE between fits from different starting sets (~2%).
MARGIN = 0.10


def _pairs(maps: Path, renders: Path | None) -> list[tuple[str, SVBRDF, torch.Tensor]]:
    out = []
    for strip in sorted(maps.glob("*.png")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the samples' off-unit normals warn; they are cleaned
            m = SVBRDF.load(strip)
        tile = m.render
        if renders is not None:
            stem = re.sub(r"_svbrdf$", "", strip.stem)
            f = renders / f"{stem}.png"
            if not f.is_file():
                continue
            tile = torch.from_numpy(np.ascontiguousarray(read_image(f)[..., :3], dtype=np.float32)).permute(2, 0, 1)[None]
        if tile is None:
            continue
        if tuple(tile.shape[-2:]) != m.resolution:
            raise SystemExit(f"{strip.name}: render {tuple(tile.shape[-2:])} but maps {m.resolution}")
        out.append((strip.stem, m, tile))
    return out


def _figure(rows: list[tuple[str, dict, torch.Tensor]], path: Path, with_tiles: bool) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = (["tile"] if with_tiles else []) + list(H) + [f"{h} - tile" for h in H]
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(2.2 * len(cols), 2.3 * len(rows)), squeeze=False)
    for r, (name, res, tile) in enumerate(rows):
        ims = ([tile] if with_tiles else []) + [res[h]["image"] for h in H]
        for c, im in enumerate(ims):
            axes[r, c].imshow(im[0].permute(1, 2, 0).clamp(0, 1).numpy())
        for k, h in enumerate(H):
            err = (res[h]["image"] - tile)[0].mean(0).numpy()
            axes[r, len(ims) + k].imshow(err, cmap="RdBu_r", vmin=-0.15, vmax=0.15)
        for c, t in enumerate(cols):
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
            if r == 0:
                axes[r, c].set_title(t, fontsize=8)
        axes[r, 0].set_ylabel(name, fontsize=8)
    fig.suptitle("flash at the camera, fitted position and scale; errors in display values (-0.15 blue .. +0.15 red)",
                 fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=60)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--maps", type=Path, default=SAMPLES, help="folder of strips (default: the samples)")
    ap.add_argument("--renders", type=Path, default=None,
                    help="folder of render tiles <stem>.png for <stem>_svbrdf.png (default: the strips' own 5th tile)")
    ap.add_argument("--fit-size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=120)
    ap.add_argument("--with-tiles", action="store_true", help="put the tiles themselves into the figure")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    torch.set_num_threads(1)
    pairs = _pairs(args.maps, args.renders)
    if not pairs:
        raise SystemExit(f"no material with a render tile in {args.maps}" + (f" / {args.renders}" if args.renders else "")
                         + ": give 5-tile strips or --renders")
    rows, csv_rows = [], []
    t0 = time.perf_counter()
    for name, m, tile in pairs:
        res = encoding.compare_encodings(m, tile, fit_size=args.fit_size, steps=args.steps)
        rows.append((name, res, tile))
        for h in encoding.HYPOTHESES:
            r = res[h]
            csv_rows.append({"material": name, "hypothesis": h, "rmse": round(r["rmse"], 4), "corr": round(r["corr"], 4),
                             "flash_x": round(r["position"][0], 3), "flash_y": round(r["position"][1], 3),
                             "flash_z": round(r["position"][2], 3), "scale": round(r["scale"], 4),
                             "kd_max": round(float(m.diffuse.max()), 3)})
        print(name, {h: (round(res[h]["rmse"], 4), round(res[h]["corr"], 4)) for h in res}, flush=True)
    elapsed = time.perf_counter() - t0
    src = "their own 5th tile" if args.renders is None else "separate render images `<i>.png` (`--renders`)"
    cmd = "python benchmarks/albedo_encoding.py" + (" --renders DIR" if args.renders else "")
    lines = [f"Command: `{cmd}`.", ""]
    if args.renders is not None and args.maps.resolve() == SAMPLES.resolve():
        lines += ["The 4 development samples (`shared/data/svbrdf_samples`, 4-tile strips) come without their render "
                  "tile. DIR holds the flash images of the same 4 materials, `presentations/final/results/0_artificial/"
                  "<i>.png` of the MIT-licensed repository mworchel/svbrdf-estimation (beside the `gt/` folder the "
                  "samples come from; 256 x 256, 8-bit); they are not bundled here, so the figure leaves the tiles out "
                  "(`--with-tiles` puts them in, for looking at locally).", ""]
    lines += [f"{len(pairs)} materials, render tiles from {src}; fit at {args.fit_size} px, {args.steps} Adam steps "
             f"from {len(encoding.STARTS)} starting positions, scored at full size ({elapsed:.0f} s).", "",
             "Per material and hypothesis: display-value RMSE and Pearson correlation of the toned render against the "
             "tile over its unsaturated pixels (lower RMSE / higher correlation is the better match), and the fitted "
             "flash position (half sides of the sample; Deschaintre et al. 2018 put the camera at z = 2.75, a 40 "
             "degree field of view) and scale of the best hypothesis. Hypotheses: `linear` stored kd and ks rendered "
             "as they are, `srgb` both sRGB-decoded first, `srgb_kd` kd decoded, ks as stored. **Bold**: the better "
             f"hypothesis; a material whose runner-up is within {MARGIN:.0%} of the best decides nothing.", "",
             "| material | kd max | " + " | ".join(f"RMSE {h}" for h in H) + " | " + " | ".join(f"corr {h}" for h in H)
             + " | flash (best) | better |", "|---|---:|" + "---:|" * (2 * len(H)) + "---|---|"]
    votes = {h: 0 for h in H}
    for name, res, _ in rows:
        ranked = sorted(H, key=lambda h: res[h]["rmse"])
        best, second = ranked[0], ranked[1]
        if res[second]["rmse"] <= (1 + MARGIN) * res[best]["rmse"]:
            better = "undecided"
        else:
            better = best
            votes[best] += 1
        cell = lambda h: f"**{res[h]['rmse']:.4f}**" if h == better else f"{res[h]['rmse']:.4f}"  # noqa: E731
        r = res[best]
        pos = "(" + ", ".join(f"{v:.2f}" for v in r["position"]) + f") x{r['scale']:.3g}"
        kd_max = float(next(m for n, m, _ in pairs if n == name).diffuse.max())
        lines.append(f"| {name} | {kd_max:.3f} | " + " | ".join(cell(h) for h in H) + " | "
                     + " | ".join(f"{res[h]['corr']:.4f}" for h in H) + f" | {pos} | {better} |")
    winners = [h for h in H if votes[h]]
    verdict = winners[0] if len(winners) == 1 else ("none decided" if not winners else "split")
    lines += ["", "Decided materials: " + ", ".join(f"{h} {votes[h]}" for h in H) + f"; verdict: **{verdict}** "
              "(one hypothesis must win every decided material).", "",
              "Figure: [albedo_encoding.png](albedo_encoding.png) (per material: the toned render under each hypothesis "
              "and its signed error against the tile).", ""]
    text = "\n".join(lines)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    _figure(rows, args.out / "albedo_encoding.png", args.with_tiles)
    write_report(args.out, "albedo_encoding", "Albedo encoding of Deschaintre-format strips", "albedo_encoding.py",
                 text, csv_rows)


if __name__ == "__main__":
    main()
