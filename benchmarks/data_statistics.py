"""Procedural materials vs the sample materials: histograms and per-material percentiles of the maps.

Run:

    .venv/bin/python benchmarks/data_statistics.py                   # 200 procedural materials at 256 px
    .venv/bin/python benchmarks/data_statistics.py --n 48 --size 64  # quick look

Quantities per texel (:mod:`mitsvbrdf.data.stats`, plus the diffuse albedo per channel): diffuse
albedo luminance and R / G / B, specular albedo (RGB mean) and its chroma (max - min over RGB),
roughness, normal slope angle; all on the stored values (the samples' maps as
:meth:`mitsvbrdf.SVBRDF.load` reads them, the generator's as it makes them). Procedural set:
materials 0..n-1 of stream seed 0; samples: the 4 strips of ``shared/data/svbrdf_samples``
(MITSVBRDF_SAMPLES), resized to ``--size`` (:meth:`SVBRDF.resized`: area average, normals
renormalised) when it is not 256.

A second table, *relief at the training resolution*, compares the normals at ``--train-size``
(64 px, the shipped networks' training resolution) with those at 256 px: per set, the flat-normal
RMSE (:func:`mitsvbrdf.metrics.flat_normal_rmse`: what a method that predicts n = +z scores) and
the median and 90th percentile of the slope angle, for the procedural set under several relief
multipliers (``bump`` of :func:`procedural.generate`) and for the samples area-resized. A 64 px
material lacks the finest, steepest detail of the same material at 256 px; the table shows which
multiplier gives back the 256 px statistics (the ``data.bump`` of the training chains).

A third table, *pure metals*, is joint where the percentiles are marginal: the specular albedo (RGB
mean) of the texels without diffuse (kd = 0), for the procedural set at ``--train-size`` without
and with ``dark_metals`` (:data:`DARK_METALS`, :func:`procedural.generate`) and for each sample that
has such texels. A dark coloured metal (2_svbrdf) passes every marginal percentile (dark specular
albedos are common: dielectrics) yet no undarkened procedural metal is that dark.

Prints and writes ``data_statistics.md`` / ``.csv`` (the per-material percentile rows) and
``data_statistics.png`` (overlaid histograms) into docs/benchmarks/. A sample percentile outside
the range of the same percentile over the procedural materials is a *miss*: the generator makes no
material that looks like the sample in that respect.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import torch

from mitsvbrdf import SVBRDF
from mitsvbrdf.data import procedural, stats
from mitsvbrdf.metrics import flat_normal_rmse
from report import SAMPLES, write_csv, write_report

ROOT = Path(__file__).resolve().parent.parent

ALBEDO = [0.0, 0.005, 0.01, 0.03, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0]
EDGES = {
    "kd_luminance": ALBEDO, "kd_r": ALBEDO, "kd_g": ALBEDO, "kd_b": ALBEDO,
    "ks": [0.0, 0.02, 0.04, 0.06, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0],
    "ks_chroma": [0.0, 0.005, 0.02, 0.05, 0.1, 0.2, 0.4, 0.7, 1.0],
    "roughness": [0.0, 0.03, 0.06, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.0],
    "slope_deg": [0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.0],
}
LABELS = {"kd_luminance": "kd luminance", "kd_r": "kd R", "kd_g": "kd G", "kd_b": "kd B", "ks": "ks (RGB mean)",
          "ks_chroma": "ks chroma (max - min)", "roughness": "roughness r", "slope_deg": "slope angle (deg)"}
PERCENTILES = (0.01, 0.5, 0.99)


def texel_maps(m: SVBRDF) -> dict[str, torch.Tensor]:
    """(B, H, W) per quantity: :func:`stats.texel_maps` plus the diffuse albedo per channel."""
    out = stats.texel_maps(m)
    for c, ch in enumerate("rgb"):
        out[f"kd_{ch}"] = m.diffuse[:, c]
    return {k: out[k] for k in EDGES}


def summarise(m: SVBRDF) -> tuple[dict[str, list[float]], dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """Histogram fractions (all texels), per-material percentiles (B, 3), and texel values for the plot."""
    vals = texel_maps(m)
    q = torch.tensor(PERCENTILES)
    hist = {k: stats.histogram(v, EDGES[k]) for k, v in vals.items()}
    pct = {k: torch.quantile(v.reshape(v.shape[0], -1).float(), q, dim=1).T for k, v in vals.items()}
    return hist, pct, {k: v.reshape(-1)[::7] for k, v in vals.items()}


def procedural_set(n: int, size: int, batch: int = 25):
    hist = {k: [0.0] * (len(e) - 1) for k, e in EDGES.items()}
    pct: dict[str, list[torch.Tensor]] = {k: [] for k in EDGES}
    plot: dict[str, list[torch.Tensor]] = {k: [] for k in EDGES}
    for s in range(0, n, batch):
        m = procedural.generate(min(batch, n - s), size=size, seed=0, start=s)
        h, p, v = summarise(m)
        w = m.batch_size / n
        for k in EDGES:
            hist[k] = [a + w * b for a, b in zip(hist[k], h[k])]
            pct[k].append(p[k])
            plot[k].append(v[k])
    return hist, {k: torch.cat(v) for k, v in pct.items()}, {k: torch.cat(v) for k, v in plot.items()}


RELIEF_BUMPS = (1.0, 1.5, 2.0, (1.0, 4.0))
#: The ``dark_metals`` fraction the pure-metal table compares with the plain stream.
DARK_METALS = 0.25


def pure_metal_row(name: str, m: SVBRDF) -> dict | None:
    """Histogram (fractions over :data:`EDGES` ``"ks"``) of the specular albedo's RGB mean on the
    texels of ``m`` without diffuse, and their share of all texels; None when it has none."""
    metal = procedural.pure_metal_texels(m.diffuse).reshape(-1)
    if not bool(metal.any()):
        return None
    ks = m.specular.mean(dim=1).reshape(-1)[metal]
    hist = stats.histogram(ks, EDGES["ks"])
    return {"set": name, "share": round(float(metal.float().mean()), 4), **{f"bin{i}": round(h, 4) for i, h in enumerate(hist)}}


def pure_metal_table(n: int, size: int, samples: list[SVBRDF]) -> list[dict]:
    """:func:`pure_metal_row` for the procedural set (materials 0..n-1, seed 0) at ``size`` without
    and with :data:`DARK_METALS`, then for every sample with pure-metal texels."""
    rows = [pure_metal_row("procedural", procedural.generate(n, size=size, seed=0)),
            pure_metal_row(f"procedural, dark_metals={DARK_METALS:g}",
                           procedural.generate(n, size=size, seed=0, dark_metals=DARK_METALS))]
    rows += [pure_metal_row(s.name, s) for s in samples]
    return [r for r in rows if r is not None]


def relief_row(name: str, size: int, bump, m: SVBRDF) -> dict:
    """Flat-normal RMSE (mean and median over materials) and slope percentiles of set ``m``."""
    flat = flat_normal_rmse(m)
    slope = stats.texel_maps(m)["slope_deg"].reshape(-1)[::3].float()
    return {"set": name, "px": size, "bump": "-" if bump is None else (f"{bump[0]:g}-{bump[1]:g}" if isinstance(bump, tuple) else f"{bump:g}"),
            "flat_rmse_mean": round(float(flat.mean()), 4), "flat_rmse_median": round(float(flat.median()), 4),
            "slope_median": round(float(slope.median()), 2), "slope_p90": round(float(torch.quantile(slope, 0.9)), 2)}


def relief_table(n: int, sizes: tuple[int, int], strips: list[Path]) -> list[dict]:
    """:func:`relief_row` for the procedural set (materials 0..n-1, seed 0) at the larger size with
    its own relief and at the smaller under :data:`RELIEF_BUMPS`, then for each sample at both."""
    small, large = sizes
    rows = [relief_row("procedural", large, 1.0, procedural.generate(n, size=large, seed=0))]
    rows += [relief_row("procedural", small, b, procedural.generate(n, size=small, seed=0, bump=b)) for b in RELIEF_BUMPS]
    for f in strips:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            full = SVBRDF.load(f)
        rows += [relief_row(full.name, px, None, full.resized(px)) for px in (small, large)]
    return rows


def _pct(x: float) -> str:
    return f"{100 * x:.1f}" if x >= 0.0005 else ("0" if x == 0 else "<0.1")


def _figure(proc_plot, sample_plot, names, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(15, 6.5))
    for ax, k in zip(axes.flat, EDGES):
        hi = 90.0 if k == "slope_deg" else 1.0
        bins = torch.linspace(0, hi, 46).tolist()
        ax.hist(proc_plot[k].numpy(), bins=bins, density=True, color="0.75", label="procedural")
        for name, v in zip(names, sample_plot):
            ax.hist(v[k].numpy(), bins=bins, density=True, histtype="step", lw=1.4, label=name)
        ax.set_yscale("log")
        ax.set_title(LABELS[k], fontsize=9)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("texel histograms (density, log scale): procedural set (grey) vs the sample materials", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--train-size", type=int, default=64, help="resolution of the relief table's smaller size")
    ap.add_argument("--samples", type=Path, default=SAMPLES)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    torch.set_num_threads(1)
    strips = sorted(args.samples.glob("*_svbrdf.png"))
    if not strips:
        raise SystemExit(f"no *_svbrdf.png strips in {args.samples}: set MITSVBRDF_SAMPLES")
    samples = []
    for f in strips:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # off-unit file normals: cleaned by the loader
            samples.append(SVBRDF.load(f).resized(args.size))
    names = [s.name for s in samples]
    t0 = time.perf_counter()
    p_hist, p_pct, p_plot = procedural_set(args.n, args.size)
    gen_s = time.perf_counter() - t0
    s_sum = [summarise(s) for s in samples]

    cmd = "python benchmarks/data_statistics.py" + ("" if (args.n, args.size) == (200, 256) else f" --n {args.n} --size {args.size}")
    lines = [f"Command: `{cmd}`.", "",
             f"Procedural: materials 0..{args.n - 1} of stream seed 0 at {args.size} x {args.size} ({gen_s:.0f} s incl. "
             f"statistics). Samples: {', '.join(names)} (`shared/data/svbrdf_samples`, stored values as loaded"
             + ("" if args.size == 256 else f", area-resized to {args.size} px") + ").", "",
             "Figure: [data_statistics.png](data_statistics.png).", "",
             "## Histograms", "", "Fraction of all texels (%) per bin; bins are [lower, upper), the last closed.", ""]
    for k, e in EDGES.items():
        head = " | ".join(f"{e[i]:g}-{e[i + 1]:g}" for i in range(len(e) - 1))
        lines += [f"**{LABELS[k]}**", "", f"| set | {head} |", "|---|" + "---:|" * (len(e) - 1),
                  "| procedural | " + " | ".join(_pct(x) for x in p_hist[k]) + " |"]
        for name, (h, _, _) in zip(names, s_sum):
            lines.append(f"| {name} | " + " | ".join(_pct(x) for x in h[k]) + " |")
        lines.append("")
    lines += ["## Per-material percentiles", "",
              "Each sample's 1st / 50th / 99th texel percentile, and in brackets the range (min - max) of the same "
              "percentile over the procedural materials; **bold** where the sample lies outside it (a miss).", "",
              "| quantity | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    rows, misses = [], []
    for k in EDGES:
        lo, hi = p_pct[k].min(0).values, p_pct[k].max(0).values
        cells = []
        for name, (_, pct, _) in zip(names, s_sum):
            parts = []
            for j, qn in enumerate(PERCENTILES):
                v = float(pct[k][0, j])
                out = v < float(lo[j]) - 1e-6 or v > float(hi[j]) + 1e-6
                parts.append(f"**{v:.3g}**" if out else f"{v:.3g}")
                rows.append({"quantity": k, "material": name, "percentile": qn, "sample": round(v, 4),
                             "procedural_min": round(float(lo[j]), 4), "procedural_max": round(float(hi[j]), 4),
                             "miss": int(out)})
                if out:
                    misses.append(f"{name} {LABELS[k]} p{int(qn * 100)} = {v:.3g}, procedural "
                                  f"{float(lo[j]):.3g} - {float(hi[j]):.3g}")
            cells.append(" / ".join(parts))
        rng = " / ".join(f"{float(a):.3g}-{float(b):.3g}" for a, b in zip(lo, hi))
        lines.append(f"| {LABELS[k]} ({rng}) | " + " | ".join(cells) + " |")
    lines += ["", f"## Misses ({len(misses)} of {len(rows)} sample percentiles)", ""]
    lines += [f"- {m}" for m in misses] or ["- none: every sample percentile lies in the procedural range."]
    relief = relief_table(args.n, (args.train_size, 256), strips)
    lines += ["", f"## Relief at the training resolution ({args.train_size} px against 256 px)", "",
              "Flat-normal RMSE (encoded normals, n = +z everywhere; mean and median over the materials of a set) "
              "and the slope angle's median and 90th percentile over its texels. Procedural materials under a "
              "relief multiplier `bump` (a range: each material's own, log-uniform in it); samples area-resized.", "",
              "| set | px | bump | flat-normal RMSE mean | median | slope median (deg) | slope p90 (deg) |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['set']} | {r['px']} | {r['bump']} | {r['flat_rmse_mean']:.4f} | {r['flat_rmse_median']:.4f} | "
              f"{r['slope_median']:.1f} | {r['slope_p90']:.1f} |" for r in relief]
    metals = pure_metal_table(args.n, args.train_size, samples)
    e = EDGES["ks"]
    lines += ["", f"## Pure metals ({args.train_size} px)", "",
              "Specular albedo (RGB mean) of the texels without diffuse (kd = 0): fraction (%) per bin, and those "
              "texels' share of the set.", "",
              "| set | share of texels | " + " | ".join(f"{e[i]:g}-{e[i + 1]:g}" for i in range(len(e) - 1)) + " |",
              "|---|---:|" + "---:|" * (len(e) - 1)]
    lines += [f"| {r['set']} | {_pct(r['share'])} | " + " | ".join(_pct(r[f'bin{i}']) for i in range(len(e) - 1)) + " |"
              for r in metals]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    _figure(p_plot, [p for _, _, p in s_sum], names, args.out / "data_statistics.png")
    write_report(args.out, "data_statistics", "Procedural materials vs the sample materials", "data_statistics.py",
                 text, rows)
    write_csv(args.out / "data_statistics_relief.csv", relief)
    write_csv(args.out / "data_statistics_pure_metals.csv", metals)


if __name__ == "__main__":
    main()
