"""Evaluation of acquisition methods on a set of materials: tables, per-material figures, HTML.

A *method* is a callable ``method(svbrdf) -> Capture`` that acquires a ground-truth material
(simulated) and reconstructs it: the adaptive pipeline (:mod:`mitsvbrdf.pipeline`), or a baseline
with fixed patterns. :func:`evaluate` runs every method on every material and measures, per
material (paper Tables 1 and 3):

* RMSE of each encoded map and their average;
* re-rendering RMSE under ``n_lights`` random point lights and under ``n_edges`` step-edge LCD
  patterns, and SSIM of the same re-renderings (display values: each ground-truth image set's
  exposure puts its 99th percentile at 1, the same exposure is used for the prediction, then the
  sRGB curve), all through the same renderer;
* LPIPS only when available locally (:func:`mitsvbrdf.metrics.lpips_model`), else a note.

Outputs in ``out_dir``: ``metrics.csv`` (one row per method and material), ``summary.md`` and
``summary.csv`` (means per method), ``figures/<material>.png`` and ``index.html``.
"""

from __future__ import annotations

import csv
import html
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import torch
from torch import Tensor

from .metrics import MAP_CHANNELS, image_rmse, image_ssim, lpips_model, map_rmse
from .patterns import step_edges
from .relight import point_light_images, random_point_lights, tonemap
from .render import render
from .rig import Rig
from .svbrdf import SVBRDF


@dataclass
class Capture:
    """What a method produced for one material: its patterns (P, 3, h, w), the images it saw
    (P, 3, H, W), and the reconstruction (B = 1)."""

    patterns: Tensor
    images: Tensor
    svbrdf: SVBRDF


#: A method maps a ground-truth material to its capture and reconstruction. The builders below
#: also set ``method.networks`` to the torch module(s) it runs, whose U-Nets decide which
#: material sizes it takes (:func:`mitsvbrdf.pipeline.size_multiple`).
Method = Callable[[SVBRDF], Capture]


@dataclass
class Relighting:
    """Novel lighting shared by all methods: point lights (L, 3) metres, LCD patterns (E, 3, h, w).

    The LCD patterns are rendered by ``method`` (default Mitsuba at ``spp`` samples with one fixed
    seed, so the ground truth and every prediction see the same sample set and the noise largely
    cancels in their difference; "reference" is exact but ~1 min per 256 x 256 material).
    """

    lights: Tensor
    edges: Tensor
    method: str = "mitsuba"
    spp: int = 256
    seed: int = 12345

    @classmethod
    def make(cls, rig: Rig, n_lights: int = 10, n_edges: int = 10, seed: int = 0, **kwargs) -> "Relighting":
        return cls(random_point_lights(n_lights, seed=seed), step_edges(*rig.lcd_cells, n=n_edges), **kwargs)

    def images(self, svbrdf: SVBRDF, rig: Rig) -> Tensor:
        """(B, L + E, 3, H, W) linear radiance."""
        pts = point_light_images(svbrdf, self.lights, rig)
        edges = render(svbrdf, self.edges, rig, method=self.method, spp=self.spp, seed=self.seed)
        return torch.cat([pts, edges], 1)


def _exposure(images: Tensor) -> Tensor:
    """Per-image exposure (L,) putting each ground-truth image's 99th percentile at 1."""
    q = torch.quantile(images.flatten(1).float(), 0.99, dim=1)
    return 1.0 / q.clamp_min(1e-12)


def score(pred: SVBRDF, gt: SVBRDF, rig: Rig, relight: Relighting) -> tuple[dict[str, float], Tensor, Tensor]:
    """Metrics of one reconstruction (B = 1); also returns the display-value re-renderings
    (ground truth, prediction), each (L + E, 3, H, W)."""
    row = {f"rmse_{k}": float(v[0]) for k, v in map_rmse(pred, gt).items()}
    with torch.no_grad():
        g, p = relight.images(gt, rig)[0], relight.images(pred, rig)[0]
    ex = _exposure(g).view(-1, 1, 1, 1)
    tg, tp = tonemap(g * ex, 1.0), tonemap(p * ex, 1.0)
    n = relight.lights.shape[0]
    row["rerender_rmse_points"] = float(image_rmse(tp[None, :n], tg[None, :n])[0])
    row["rerender_rmse_edges"] = float(image_rmse(tp[None, n:], tg[None, n:])[0])
    row["rerender_rmse"] = float(image_rmse(tp[None], tg[None])[0])
    row["ssim"] = float(image_ssim(tp[None], tg[None])[0])
    return row, tg, tp


def evaluate(methods: dict[str, Method], materials: Iterable[SVBRDF], rig: Rig, out_dir: str | Path, *,
             relight: Relighting | None = None, figures: bool = True, max_figures: int | None = None,
             progress: bool = True) -> list[dict]:
    """Run every method on every material; write the tables, figures and index (module docstring).
    ``max_figures`` limits the figures to the first materials (they are large: one row of images
    per method).

    Returns the per-material rows. Raises MaterialError (a ValueError) for an empty material set.
    """
    from tqdm import tqdm

    from .errors import MaterialError
    from .pipeline import check_resolution, size_multiple

    materials = list(materials)
    if not materials:  # before the folder is made
        raise MaterialError("no materials to evaluate")
    need = size_multiple(*(getattr(m, "networks", torch.nn.Module()) for m in methods.values()))
    for i, gt in enumerate(materials):  # every size the methods' networks cannot take, before any work
        check_resolution(gt.resolution, need, f"material {gt.name or i}")
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    relight = relight or Relighting.make(rig)
    lp, lp_note = lpips_model()
    rows: list[dict] = []
    figs: list[tuple[str, str]] = []
    bar = tqdm(total=len(materials) * len(methods), desc="evaluate", disable=not progress)
    seen: set[str] = set()
    for i, gt in enumerate(materials):
        name = gt.name or f"material_{i:03d}"
        if name in seen:  # rows and figures are keyed by name
            name = f"{name}_{i:03d}"
        seen.add(name)
        shown = {}
        for mname, method in methods.items():
            cap = method(gt)
            if cap.svbrdf.resolution != gt.resolution:
                raise ValueError(f"method {mname!r} returned {cap.svbrdf.resolution} maps for the "
                                 f"{gt.resolution} material {name}")
            row, tg, tp = score(cap.svbrdf, gt, rig, relight)
            if lp is not None:
                with torch.no_grad():
                    row["lpips"] = float(lp(tp * 2 - 1, tg * 2 - 1).mean())
            rows.append({"method": mname, "material": name, **row})
            shown[mname] = (cap, tp)
            bar.update(1)
        if figures and (max_figures is None or len(figs) < max_figures):
            path = out / "figures" / f"{_file_stem(name)}.png"
            material_figure(gt, shown, tg, path)
            figs.append((name, f"figures/{path.name}"))
    bar.close()
    _write_tables(rows, out, lp_note)
    _write_index(out, figs, lp_note)
    return rows


SUMMARY_COLUMNS = ["rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_average",
                   "rerender_rmse", "ssim"]


def summarize(rows: list[dict]) -> list[dict]:
    """Mean of every metric per method, in the order methods first appear."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        sel = [r for r in rows if r["method"] == m]
        keys = [k for k in sel[0] if k not in ("method", "material")]
        out.append({"method": m, "materials": len(sel), **{k: float(np.mean([r[k] for r in sel])) for k in keys}})
    return out


def _write_tables(rows: list[dict], out: Path, lp_note: str) -> None:
    with open(out / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    summary = summarize(rows)
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(summary[0]))
        w.writeheader()
        w.writerows(summary)
    cols = SUMMARY_COLUMNS + (["lpips"] if "lpips" in summary[0] else [])
    heads = {"rmse_normal": "Normal", "rmse_diffuse": "Diffuse", "rmse_roughness": "Roughness",
             "rmse_specular": "Specular", "rmse_average": "Average", "rerender_rmse": "Re-render RMSE",
             "ssim": "SSIM", "lpips": "LPIPS"}
    lines = ["| Method | " + " | ".join(heads[c] for c in cols) + " |", "|---|" + "---:|" * len(cols)]
    lines += [f"| {s['method']} | " + " | ".join(f"{s[c]:.4f}" for c in cols) + " |" for s in summary]
    note = f"\n\n{lp_note}." if lp_note else ""
    (out / "summary.md").write_text(
        f"Map RMSE on encoded maps and re-rendering metrics, mean over {summary[0]['materials']} materials.\n\n"
        + "\n".join(lines) + note + "\n")


def _write_index(out: Path, figs: list[tuple[str, str]], lp_note: str) -> None:
    table = (out / "summary.md").read_text().split("\n\n")[1]
    body = "".join(f'<h2>{html.escape(n)}</h2><img src="{html.escape(p)}" style="max-width:100%">' for n, p in figs)
    (out / "index.html").write_text(
        "<!doctype html><html><head><meta charset='utf-8'><title>mitsvbrdf evaluation</title></head><body>"
        f"<h1>Evaluation</h1><pre>{html.escape(table)}</pre><p>{html.escape(lp_note)}</p>{body}</body></html>\n")


def _file_stem(name: str) -> str:
    """A material name as a portable file name: characters other than letters, digits, ``.``,
    ``_`` and ``-`` (e.g. the colons of "procedural:1000000:0") become ``-``."""
    return re.sub(r"[^A-Za-z0-9._-]", "-", name).strip(".") or "material"


def _display(t: Tensor) -> np.ndarray:
    """(3, H, W) or (1, H, W) values in [0, 1] -> (H, W, 3) array."""
    t = t.detach().float().cpu().clamp(0, 1)
    if t.shape[0] == 1:
        t = t.expand(3, *t.shape[1:])
    return t.permute(1, 2, 0).numpy()


def material_figure(gt: SVBRDF, shown: dict[str, tuple[Capture, Tensor]], gt_relit: Tensor, path: Path) -> None:
    """One PNG per material: per method a row of patterns + captured images, the maps (GT row
    first), error maps, and re-renderings (GT row first)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(MAP_CHANNELS)
    n_relit = min(4, gt_relit.shape[0])
    rows = 1 + 3 * len(shown)
    cols = max(10, len(names) + n_relit)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 1.3, rows * 1.4))
    for ax in axes.flat:
        ax.axis("off")
    enc_gt = gt.encoded()[0]

    def put(r, c, img, title=""):
        ax = axes[r, c]
        ax.axis("on")  # keep the frame: a white pattern must not vanish into the page
        ax.set_xticks([])
        ax.set_yticks([])
        ax.imshow(img)
        ax.set_title(title, fontsize=6)

    for c, k in enumerate(names):
        put(0, c, _display(enc_gt[MAP_CHANNELS[k]]), f"GT {k}")
    for c in range(n_relit):
        put(0, len(names) + c, _display(gt_relit[c]), "GT relit")
    for m, (name, (cap, relit)) in enumerate(shown.items()):
        r0 = 1 + 3 * m
        p = cap.patterns.shape[0]
        scale = 1.0 / float(torch.quantile(cap.images.flatten().float(), 0.99).clamp_min(1e-12))
        for c in range(min(p, cols // 2)):
            put(r0, 2 * c, _display(cap.patterns[c]), f"{name}: L{c}")
            put(r0, 2 * c + 1, _display(tonemap(cap.images[c], scale)), f"I{c}")
        enc = cap.svbrdf.encoded()[0]
        for c, k in enumerate(names):
            put(r0 + 1, c, _display(enc[MAP_CHANNELS[k]]), f"{name} {k}")
            diff = enc[MAP_CHANNELS[k]] - enc_gt[MAP_CHANNELS[k]]
            put(r0 + 2, c, _display(diff.abs().mean(0, keepdim=True) * 4),
                f"|error| x4 (rmse {float(diff.square().mean().sqrt()):.3f})")
        for c in range(n_relit):
            put(r0 + 1, len(names) + c, _display(relit[c]), "relit")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fixed_pattern_method(patterns: Tensor, reconstructor: Callable[[Tensor, Tensor], Tensor], rig: Rig, *,
                         method: str = "mitsuba", spp: int = 64, seed: int = 0) -> Method:
    """A baseline that captures with fixed ``patterns`` (P, 3, h, w) and reconstructs with
    ``reconstructor(images (1, P, 3, H, W), patterns) -> (1, 10, H, W)`` encoded maps."""
    from .pipeline import maps_to_svbrdf

    def run(gt: SVBRDF) -> Capture:
        with torch.no_grad():
            imgs = render(gt, patterns, rig, method=method, spp=spp, seed=seed)
            pred = maps_to_svbrdf(reconstructor(imgs, patterns))
        return Capture(patterns, imgs[0], pred)

    return run


def adaptive_method(pipeline, *, method: str = "mitsuba", spp: int = 64, seed: int = 0) -> Method:
    """The adaptive pipeline as an evaluation method (simulated capture)."""

    def run(gt: SVBRDF) -> Capture:
        acq = pipeline.simulate(gt, method=method, spp=spp, seed=seed)
        return Capture(acq.patterns, acq.images, acq.svbrdf)

    run.networks = pipeline
    return run


def flash_method(flash, reconstructor: Callable[[Tensor], Tensor], rig: Rig) -> Method:
    """The flash baseline: one image under ``flash`` (a :class:`mitsvbrdf.relight.FlashLight`),
    ``reconstructor(images (1, 1, 3, H, W)) -> (1, 10, H, W)`` encoded maps. Its capture shows a
    black LCD pattern: the LCD is off."""
    from .pipeline import maps_to_svbrdf

    dark = torch.zeros(1, 3, *rig.lcd_cells)

    def run(gt: SVBRDF) -> Capture:
        with torch.no_grad():
            imgs = flash(gt, rig)
            pred = maps_to_svbrdf(reconstructor(imgs))
        return Capture(dark, imgs[0], pred)

    return run


def baseline_method(path: str | Path, rig: Rig, *, spp: int = 64, seed: int = 0) -> Method:
    """A baseline from the ``networks.pt`` export of a ``fixed`` training stage: its pattern group
    (fixed or learned) or its flash, and its G_sc. Raises NetworkFileError for other files."""
    from .nets import NetworkFileError, network_from_record
    from .nets.io import read_network_file
    from .separation import reconstruct_maps

    recs = read_network_file(path, "baseline networks")
    if not isinstance(recs, dict) or "svbrdf" not in recs or not ({"patterns", "flash"} & set(recs)):
        have = sorted(recs) if isinstance(recs, dict) else type(recs).__name__
        raise NetworkFileError(f"{path}: a baseline needs networks 'svbrdf' and 'patterns' (or 'flash'), "
                               f"the file has {have} (use the export of a 'fixed' stage)")
    net = network_from_record(recs["svbrdf"], f"{path}: svbrdf").eval()
    if "flash" in recs:
        run = flash_method(network_from_record(recs["flash"], f"{path}: flash"), net, rig)
        run.networks = net
        return run
    pats = network_from_record(recs["patterns"], f"{path}: patterns")().detach()
    if tuple(pats.shape[1:]) != (3, *rig.lcd_cells):
        raise NetworkFileError(f"{path}: patterns {tuple(pats.shape[1:])} do not fit this rig's LCD "
                               f"{(3, *rig.lcd_cells)}")
    run = fixed_pattern_method(pats, lambda images, patterns: reconstruct_maps(net, images, patterns, rig), rig,
                               spp=spp, seed=seed)
    run.networks = net
    return run

