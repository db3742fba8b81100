"""Evaluation of acquisition methods on a set of materials: tables, per-material figures, HTML.

A *method* is a callable ``method(svbrdf) -> Acquisition`` that acquires a ground-truth material
(simulated) and reconstructs it: :func:`simulated` makes one of any acquisition of
:mod:`mitsvbrdf.acquisition` (the adaptive method or a baseline). :func:`evaluate` runs every method on every material and measures, per
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
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from .acquisition import Acquisition, check_resolution, size_multiple
from .data.procedural import generate
from .errors import MaterialError
from .metrics import flat_normal_rmse, image_rmse, image_ssim, lpips_model, map_rmse
from .patterns import step_edges
from .relight import point_light_images, random_point_lights
from .render import render
from .rig import Rig
from .svbrdf import SVBRDF
from .training.config import TEST_SEED_BASE
from .viewing import auto_exposure, material_figure, tonemap, write_html_page


#: A method maps a ground-truth material to its acquisition. :func:`simulated` also sets
#: ``method.networks`` to the torch module(s) it runs, whose U-Nets decide which material sizes
#: it takes (:func:`mitsvbrdf.acquisition.size_multiple`).
Method = Callable[[SVBRDF], Acquisition]


def simulated(acquisition, *, method: str = "mitsuba", spp: int = 64, seed: int = 0) -> Method:
    """An acquisition of :mod:`mitsvbrdf.acquisition` (adaptive, fixed patterns or flash) as an
    evaluation method: its simulated capture of each ground truth through ``method``."""

    def run(gt: SVBRDF) -> Acquisition:
        return acquisition.simulate(gt, method=method, spp=spp, seed=seed)

    run.networks = acquisition
    return run


def load_materials(data: str, size: int, n: int) -> list[SVBRDF]:
    """Materials for evaluation: "procedural" (``n`` held-out seeds) or a folder of strips / map
    folders / EXR files (the first ``n``, all for 0), each resampled to size x size."""
    if data == "procedural":
        mats = generate(n, size=size, seed=TEST_SEED_BASE)
        out = []
        for i in range(n):
            m = mats[i]
            m.name = f"procedural:{TEST_SEED_BASE}:{i}"  # the batch's name is its first index
            out.append(m)
        return out
    root = Path(data)
    if not root.is_dir():
        raise MaterialError(f"--data {data!r} is neither 'procedural' nor a folder")
    paths = sorted(p for p in root.iterdir() if p.suffix.lower() in (".png", ".exr") or p.is_dir())
    if not paths:
        raise MaterialError(f"no materials found in {root} (expected strip PNGs, EXR files or folders of maps)")
    return [SVBRDF(**SVBRDF.load(p).resized(size).maps(), name=p.stem) for p in (paths[:n] if n else paths)]


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


def score(pred: SVBRDF, gt: SVBRDF, rig: Rig, relight: Relighting) -> tuple[dict[str, float], Tensor, Tensor]:
    """Metrics of one reconstruction (B = 1); also returns the display-value re-renderings
    (ground truth, prediction), each (L + E, 3, H, W)."""
    row = {f"rmse_{k}": float(v[0]) for k, v in map_rmse(pred, gt).items()}
    with torch.no_grad():
        g, p = relight.images(gt, rig)[0], relight.images(pred, rig)[0]
    ex = auto_exposure(g, per_image=True).view(-1, 1, 1, 1)  # each ground-truth image's own
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
    summary = summarize(rows)
    flat = float(np.mean([float(flat_normal_rmse(gt)[0]) for gt in materials]))
    _write_tables(rows, summary, out, lp_note, flat)
    cols = _columns(summary)
    write_html_page(out / "index.html", "Evaluation", paragraphs=[_caption(summary, flat), lp_note],
                    table=(["Method"] + [HEADS[c] for c in cols],
                           [[s["method"]] + [f"{s[c]:.4f}" for c in cols] for s in summary]),
                    images=figs)
    return rows


MAP_COLUMNS = ["rmse_normal", "rmse_diffuse", "rmse_roughness", "rmse_specular", "rmse_average"]
SUMMARY_COLUMNS = MAP_COLUMNS + ["rerender_rmse", "ssim"]


def summarize(rows: list[dict]) -> list[dict]:
    """Mean of every metric per method, in the order methods first appear."""
    out = []
    for m in dict.fromkeys(r["method"] for r in rows):
        sel = [r for r in rows if r["method"] == m]
        keys = [k for k in sel[0] if k not in ("method", "material")]
        out.append({"method": m, "materials": len(sel), **{k: float(np.mean([r[k] for r in sel])) for k in keys}})
    return out


@dataclass(frozen=True)
class Paired:
    """A paired per-material difference ``b - a`` of one score: its mean, the mean's standard
    error (nan for one material), on how many materials ``a`` scored lower, and of how many."""

    mean: float
    se: float
    a_lower: int
    n: int

    def __str__(self) -> str:
        return f"{self.mean:+.4f} +- {self.se:.4f}"


def paired(a, b) -> Paired:
    """The paired difference ``b - a`` of two equally long sequences of scores, element by element
    (the same materials in the same order). ValueError when they are empty or differ in length."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or not a.size:
        raise ValueError(f"paired scores need two equally long, non-empty sequences; got {a.size} and {b.size}")
    d = b - a
    se = float(d.std(ddof=1) / len(d) ** 0.5) if len(d) > 1 else float("nan")
    return Paired(float(d.mean()), se, int((d > 0).sum()), len(d))


def paired_difference(rows: list[dict], a: str, b: str, key: str = "rmse_average", group: str = "method") -> Paired:
    """Score ``key`` of method ``b`` minus method ``a`` over the materials both scored (rows as in
    metrics.csv: the method under ``group``, ``material`` and the scores). ValueError when they
    share none."""
    by = {(r[group], r["material"]): float(r[key]) for r in rows}
    common = [(v, by[(b, m)]) for (meth, m), v in by.items() if meth == a and (b, m) in by]
    if not common:
        raise ValueError(f"methods {a!r} and {b!r} scored no material in common")
    return paired(*zip(*common))


def paired_table(rows: list[dict], methods: list[str]) -> list[str]:
    """Markdown lines: every map's paired per-material difference of ``methods[1:]`` against
    ``methods[0]`` (rows as in metrics.csv), and on how many materials ``methods[0]`` has the lower
    average. ValueError when a method shares no material with the first."""
    ref = methods[0]
    lines = [f"Paired per-material differences against {ref} (mean +- standard error; negative: "
             f"lower than {ref}), and on how many materials {ref} is lower (average):", "",
             "| Method | " + " | ".join(HEADS[c] for c in MAP_COLUMNS) + f" | {ref} lower |",
             "|---|" + "---:|" * (len(MAP_COLUMNS) + 1)]
    for m in methods[1:]:
        d = {c: paired_difference(rows, ref, m, c) for c in MAP_COLUMNS}
        lines.append(f"| {m} | " + " | ".join(str(d[c]) for c in MAP_COLUMNS) +
                     f" | {d['rmse_average'].a_lower}/{d['rmse_average'].n} |")
    return lines


HEADS = {"rmse_normal": "Normal", "rmse_diffuse": "Diffuse", "rmse_roughness": "Roughness",
         "rmse_specular": "Specular", "rmse_average": "Average", "rerender_rmse": "Re-render RMSE",
         "ssim": "SSIM", "lpips": "LPIPS"}


def _columns(summary: list[dict]) -> list[str]:
    return SUMMARY_COLUMNS + (["lpips"] if "lpips" in summary[0] else [])


def _caption(summary: list[dict], flat_normal: float) -> str:
    return (f"Map RMSE on encoded maps and re-rendering metrics, mean over {summary[0]['materials']} materials. "
            f"A flat normal map scores normal RMSE {flat_normal:.4f} on them: a method near that level has not "
            f"recovered the normals.")


def _write_tables(rows: list[dict], summary: list[dict], out: Path, lp_note: str, flat_normal: float) -> None:
    with open(out / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(summary[0]))
        w.writeheader()
        w.writerows(summary)
    cols = _columns(summary)
    lines = ["| Method | " + " | ".join(HEADS[c] for c in cols) + " |", "|---|" + "---:|" * len(cols)]
    lines += [f"| {s['method']} | " + " | ".join(f"{s[c]:.4f}" for c in cols) + " |" for s in summary]
    methods = [m["method"] for m in summary]
    if len(methods) > 1 and summary[0]["materials"] > 1:
        lines += [""] + paired_table(rows, methods)
    note = f"\n\n{lp_note}." if lp_note else ""
    (out / "summary.md").write_text(_caption(summary, flat_normal) + "\n\n" + "\n".join(lines) + note + "\n")


def _file_stem(name: str) -> str:
    """A material name as a portable file name: characters other than letters, digits, ``.``,
    ``_`` and ``-`` (e.g. the colons of "procedural:1000000:0") become ``-``."""
    return re.sub(r"[^A-Za-z0-9._-]", "-", name).strip(".") or "material"
