"""What G_sc should see: the captures alone (the paper) or also each capture over its pattern's
flat-Lambertian irradiance L^d (``model.diffuse_ratio``), and at which spp the captures are rendered.

    .venv/bin/python benchmarks/svbrdf_inputs.py                  # trains, scores, writes docs/benchmarks/svbrdf_inputs.*
    .venv/bin/python benchmarks/svbrdf_inputs.py --eval-only      # re-score finished runs
    .venv/bin/python benchmarks/svbrdf_inputs.py --quick          # smoke run (tiny), nothing written

The protocol is benchmarks/training_renderer.py's (whose functions it uses): every run is
``train/fixed-monograd-small.toml`` at ``--size`` px, width ``--width``, ``--steps`` steps, batch 4,
seed 4, here with the chains' normal weight (``loss.map_weights = [5, 1, 1, 1]``); runs differ only
in what the name says:

* ``images-4spp``: the paper's inputs, captures at 4 spp from the integrator with the ``ltc``
  control variate (the default when the study was recorded);
* ``ratio-4spp``: the same plus the diffuse-ratio inputs log((I + f) / (L^d + f));
* ``ratio-16spp``: the same at 16 spp (a quarter of the capture noise, docs/benchmarks/render_tradeoff.md).

Scores: map RMSE (encoded maps) on ``--eval-n`` held-out procedural materials captured by the
reference renderer, mean over materials, plus the flat-normal RMSE of the same set (a G_sc whose
normal RMSE sits there has not learned normals), and paired differences against ``images-4spp``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from training_renderer import (MAPS, paired_lines, probe_seconds_per_step, score, score_rows,  # noqa: E402
                                study_parser, study_runs, table_lines, train)

WEIGHTS = "loss.map_weights=[5.0, 1.0, 1.0, 1.0]"
#: The integrator the recorded study ran with (the default then), kept so that a rerun reproduces it.
LTC_CV = {"control_variate": "ltc"}
RUNS = {
    "images-4spp": (['render.method="mitsuba"', "render.spp=4", WEIGHTS], LTC_CV),
    "ratio-4spp": (['render.method="mitsuba"', "render.spp=4", WEIGHTS, "model.diffuse_ratio=true"], LTC_CV),
    "ratio-16spp": (['render.method="mitsuba"', "render.spp=16", WEIGHTS, "model.diffuse_ratio=true"], LTC_CV),
}
BASE = "images-4spp"


def main() -> None:
    ap = study_parser(__doc__, RUNS, 1000, "svbrdf_inputs")
    args = ap.parse_args()
    names = study_runs(ap, args, RUNS)
    args.seed = 4
    for name in names:
        if not (args.eval_only or (args.work / name / "networks.pt").exists()):
            train(name, args.work / name, args, RUNS)
    probed = {} if args.quick or args.no_probe else {n: probe_seconds_per_step(n, args, RUNS) for n in names}

    import mitsvbrdf as ms
    from mitsvbrdf.data.procedural import generate
    from mitsvbrdf.training.config import TEST_SEED_BASE

    rig = ms.Rig.from_scene()
    held_out = generate(args.eval_n, size=args.size, seed=TEST_SEED_BASE)
    materials = [held_out[i] for i in range(args.eval_n)]
    keys = ["rmse_average"] + ["rmse_" + m for m in MAPS]
    scores = {n: score(args.work / n / "networks.pt", materials, rig) for n in names
              if (args.work / n / "networks.pt").exists()}
    rows = score_rows(scores, probed)
    from mitsvbrdf.metrics import flat_normal_rmse

    flat = sum(float(flat_normal_rmse(m)[0]) for m in materials) / len(materials)
    lines = ["Command: `python benchmarks/svbrdf_inputs.py " + " ".join(sys.argv[1:]) + "`", "",
             f"G_sc (fixed MonoGrad, {args.size} px, width {args.width}, {args.steps} steps, batch 4, seed 4, "
             f"normal weight 5) with each run's inputs and capture spp; map RMSE (encoded maps) on {args.eval_n} "
             f"held-out procedural materials captured by the reference renderer, mean over materials "
             f"({torch.get_num_threads()} threads for the step times).", "", *table_lines(rows, keys)]
    lines += ["", f"A flat normal map (0, 0, 1) scores normal RMSE {flat:.4f} on these materials."]
    if BASE in scores and len(scores) > 1:
        lines += ["", f"Paired differences against {BASE} over the same materials: mean +- standard error; "
                      f"negative means lower error.", "", *paired_lines(scores, BASE, keys)]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.quick or not rows:
        return
    from report import write_report

    write_report(args.out, "svbrdf_inputs", "G_sc inputs and capture spp", "svbrdf_inputs.py", text, rows)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", str(os.cpu_count() or 1))
    main()
