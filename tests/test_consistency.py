"""The commands compute what the API computes, and twice the same (32 px, 2 spp, shipped networks).

Each CLI output here is compared with the same quantity computed separately through the API
(another process state, the same seeds): equality shows both that the command is a thin front end
over the acquisition layer and that the outputs are deterministic.
"""

import csv
import json

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import imageio
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, SETTINGS_KEY, load_adaptive
from mitsvbrdf.cli import main
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.evaluation import Relighting, evaluate, load_materials, score, simulated
from mitsvbrdf.nets import network_record
from mitsvbrdf.patterns import load_patterns
from mitsvbrdf.rig import DEFAULT_SCENE
from mitsvbrdf.training import STAGES, RenderSettings


def test_demo_metrics_and_captures_are_those_of_the_api(tmp_path, rig):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--resolution", "32", "--spp", "2", "--seed", "1", "--quiet"]) == 0
    gt = ms.SVBRDF.load(DEFAULT_MATERIAL).resized(32)
    acq = load_adaptive(DEFAULT_NETWORKS, rig).simulate(gt, spp=2, seed=1)
    metrics, _, _ = score(acq.svbrdf, gt, rig, Relighting.make(rig, n_lights=4, n_edges=4, seed=1))
    assert json.loads((out / "demo.json").read_text())["metrics"] == {k: round(v, 5) for k, v in metrics.items()}
    for k in range(5):
        assert torch.equal(torch.from_numpy(imageio.read_image(out / f"image_{k:02d}.exr")).permute(2, 0, 1),
                           acq.images[k])


def _rows(path):
    with open(path) as f:
        return [{k: v if k in ("method", "material") else float(v) for k, v in r.items()} for r in csv.DictReader(f)]


def test_evaluate_scores_are_those_of_the_api(tmp_path, rig):
    out = tmp_path / "eval"
    assert main(["evaluate", "--model", str(DEFAULT_NETWORKS), "--data", "procedural", "--n", "1", "--size", "32",
                 "--spp", "2", "--figures", "0", "--out", str(out), "--quiet"]) == 0
    method = simulated(load_adaptive(DEFAULT_NETWORKS, rig), spp=2, seed=0)
    rows = evaluate({"adaptive": method}, load_materials("procedural", 32, 1), rig, tmp_path / "api", figures=False,
                    progress=False)
    assert _rows(out / "metrics.csv") == _rows(tmp_path / "api" / "metrics.csv")
    assert _rows(out / "metrics.csv")[0]["rmse_average"] == pytest.approx(rows[0]["rmse_average"], rel=1e-12)


def test_simulate_writes_the_renders_of_the_api(tmp_path, rig):
    out = tmp_path / "sim"
    assert main(["simulate", str(DEFAULT_SCENE), "--material", str(DEFAULT_MATERIAL), "--patterns", "monograd",
                 "--resolution", "32", "--spp", "2", "--seed", "3", "--out", str(out), "--quiet"]) == 0
    with torch.no_grad():
        want = ms.render(ms.SVBRDF.load(DEFAULT_MATERIAL).resized(32), load_patterns("monograd", *rig.lcd_cells), rig,
                         method="mitsuba", spp=2, seed=3)[0]
    for k in range(want.shape[0]):
        assert torch.equal(torch.from_numpy(imageio.read_image(out / f"image_{k:02d}.exr")).permute(2, 0, 1), want[k])


def test_an_export_that_says_uniform_lpdf_scores_as_the_explicit_override(tmp_path, rig):
    torch.manual_seed(0)
    S = STAGES["stage2"]
    stage = S(S.Model(lighting_width=4, svbrdf_width=4, lpdf_from="uniform"), S.Loss(), RenderSettings(), rig)
    recs = {n: network_record(m) for n, m in stage.networks().items()}
    torch.save({**recs, SETTINGS_KEY: stage.acquisition_settings().record()}, tmp_path / "new.pt")
    torch.save(recs, tmp_path / "old.pt")  # written before exports carried their settings
    out = tmp_path / "eval"
    assert main(["evaluate", "--model", str(tmp_path / "new.pt"), "--uniform-lpdf", f"old={tmp_path / 'old.pt'}",
                 "--adaptive", f"old-as-is={tmp_path / 'old.pt'}", "--data", "procedural", "--n", "1", "--size", "32",
                 "--spp", "2", "--figures", "0", "--out", str(out), "--quiet"]) == 0
    by = {r["method"]: {k: v for k, v in r.items() if k != "method"} for r in _rows(out / "metrics.csv")}
    assert by["adaptive"] == by["old"]
    assert by["adaptive"] != by["old-as-is"]  # read without its setting, the L_pdf is the initializer's
