"""``mitsvbrdf demo``: the whole method on one material, from embedded defaults.

Picks the bundled example material, simulates the capture through the scene file's Mitsuba
plugins (L_0 first), predicts the 4 adaptive patterns with the shipped networks, "captures" them,
reconstructs the SVBRDF, and writes into the output folder:

* ``maps.png`` (encoded strip) and ``maps.exr`` (linear, layered) of the reconstruction, and
  ``ground_truth.png`` for comparison;
* ``patterns.png`` (L_0..L_4), ``images.png`` (tone-mapped captures) and ``image_XX.exr``;
* ``relit.png``: ground truth vs reconstruction under novel point lights and LCD step edges;
* ``summary.png`` (patterns, captures, maps, error maps, re-renderings) and ``report.html``;
* ``export/``: the reconstruction as a Mitsuba scene and as glTF maps;
* ``demo.json``: settings, timings and the error metrics.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import torch
from tqdm import tqdm

from . import imageio
from .acquisition import DEFAULT_NETWORKS, load_adaptive
from .checks import check_out_dir
from .evaluation import Relighting, score
from .export import export_gltf, export_mitsuba_scene
from .resolution import DEFAULT_TRANSFER
from .rig import Rig
from .svbrdf import SVBRDF
from .viewing import material_figure, pattern_strip, tonemap, write_html_page

#: The bundled example material, shipped inside the package (MIT, see examples/LICENSE-MIT beside it).
DEFAULT_MATERIAL = Path(__file__).resolve().parent / "examples" / "artificial_0.png"


def run_demo(out: str | Path, *, material: str | Path = DEFAULT_MATERIAL, networks: str | Path = DEFAULT_NETWORKS,
             scene: str | Path | None = None, resolution: int = 256, spp: int = 64, seed: int = 0,
             transfer: str = DEFAULT_TRANSFER, progress: bool = True) -> dict:
    """Run the demo (module docstring); returns the record written to ``demo.json``. ``transfer``:
    how the networks reconstruct a resolution finer than they trained on (:mod:`mitsvbrdf.resolution`)."""
    out = check_out_dir("out", out)
    steps = ["load", "capture + reconstruct", "re-render", "write"]
    t0 = time.perf_counter()
    rig = Rig.from_scene(scene)
    acquisition = load_adaptive(networks, rig, transfer=transfer)
    acquisition.check_resolution(resolution, "resolution")  # before rendering anything
    gt = SVBRDF.load(material).resized(resolution)
    bar = tqdm(total=len(steps), desc="demo", disable=not progress)
    bar.set_postfix_str(steps[1])
    bar.update(1)
    t1 = time.perf_counter()
    acq = acquisition.simulate(gt, method="mitsuba", spp=spp, seed=seed)
    t2 = time.perf_counter()
    bar.set_postfix_str(steps[2])
    bar.update(1)
    relight = Relighting.make(rig, n_lights=4, n_edges=4, seed=seed)
    metrics, gt_relit, pred_relit = score(acq.svbrdf, gt, rig, relight)
    bar.set_postfix_str(steps[3])
    bar.update(1)
    out.mkdir(parents=True, exist_ok=True)  # only now: a failed run leaves no folder behind
    acq.svbrdf.save(out / "maps.png")
    acq.svbrdf.save(out / "maps.exr")
    gt.save(out / "ground_truth.png", include_render=False)
    imageio.write_png(out / "patterns.png", pattern_strip(acq.patterns))
    imageio.write_png(out / "images.png", pattern_strip(tonemap(acq.images)))
    for k, img in enumerate(acq.images):
        imageio.write_exr(out / f"image_{k:02d}.exr", img.permute(1, 2, 0).numpy())
    relit = torch.cat([gt_relit, pred_relit], -2)  # ground truth above, reconstruction below
    imageio.write_png(out / "relit.png", pattern_strip(relit))
    material_figure(gt, {"adaptive": (acq, pred_relit)}, gt_relit,
                    out / "summary.png")
    export_mitsuba_scene(acq.svbrdf, out / "export" / "mitsuba", rig)
    export_gltf(acq.svbrdf, out / "export" / "gltf", sample_size=rig.sample_size)
    record = {"material": str(material), "networks": str(networks), "resolution": resolution, "spp": spp,
              "seed": seed, "transfer": transfer, "trained_resolution": acquisition.settings.resolution,
              "seconds": {"total": None, "capture_and_reconstruction": round(t2 - t1, 2)},
              "metrics": {k: round(v, 5) for k, v in metrics.items()}}
    record["seconds"]["total"] = round(time.perf_counter() - t0, 2)
    (out / "demo.json").write_text(json.dumps(record, indent=2))
    _report(out, record)
    bar.update(1)
    bar.close()
    return record


def _report(out: Path, record: dict) -> None:
    write_html_page(
        out / "report.html", "mitsvbrdf demo",
        paragraphs=[f"{record['material']} at {record['resolution']} px, {record['spp']} spp, "
                    f"{record['seconds']['total']} s. Networks trained at "
                    f"{record['trained_resolution'] or 'an unrecorded'} px, resolution transfer {record['transfer']!r}."],
        table=(["metric", "value"], list(record["metrics"].items())),
        images=[("Summary", "summary.png"), ("Patterns L0..L4", "patterns.png"), ("Captured images", "images.png"),
                ("Re-rendered: ground truth (top) vs reconstruction (bottom)", "relit.png"),
                ("Reconstructed maps", "maps.png"), ("Ground truth maps", "ground_truth.png")])
