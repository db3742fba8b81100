"""The demo (main job) and the evaluate command on a tiny configuration."""

import json

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.cli import main
from mitsvbrdf.nets import network_record
from mitsvbrdf.training import STAGES, RenderSettings


@pytest.fixture(scope="module")
def networks(tmp_path_factory, rig):
    """An untrained stage-2 export with tiny networks (the wiring, not the quality, is tested)."""
    torch.manual_seed(0)
    S = STAGES["stage2"]
    stage = S(S.Model(lighting_width=4, svbrdf_width=4), S.Loss(), RenderSettings(), rig)
    path = tmp_path_factory.mktemp("nets") / "networks.pt"
    torch.save({n: network_record(m) for n, m in stage.networks().items()}, path)
    return path


def test_demo_writes_maps_patterns_relit_summary_report_and_exports(tmp_path, networks):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--networks", str(networks), "--resolution", "32", "--spp", "2",
                 "--quiet"]) == 0
    for f in ("maps.png", "maps.exr", "ground_truth.png", "patterns.png", "images.png", "image_04.exr", "relit.png",
              "summary.png", "report.html", "demo.json", "export/mitsuba/scene.xml", "export/gltf/material.gltf"):
        assert (out / f).exists(), f
    rec = json.loads((out / "demo.json").read_text())
    assert 0 <= rec["metrics"]["rmse_average"] <= 1
    assert ms.SVBRDF.load(out / "maps.exr").resolution == (32, 32)


def test_evaluate_scores_the_model_on_a_folder_of_materials(tmp_path, networks):
    data = tmp_path / "mats"
    data.mkdir()
    ms.SVBRDF.constant(size=48, roughness=0.3).save(data / "a.png")  # another resolution: resampled
    out = tmp_path / "eval"
    assert main(["evaluate", "--model", str(networks), "--data", str(data), "--size", "32", "--spp", "2",
                 "--out", str(out), "--quiet"]) == 0
    assert "| adaptive |" in (out / "summary.md").read_text()


def test_evaluate_on_an_empty_folder_is_a_clear_error(tmp_path, networks, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["evaluate", "--model", str(networks), "--data", str(tmp_path / "empty"), "--out",
                 str(tmp_path / "o"), "--quiet"]) == 2
    assert "no materials found" in capsys.readouterr().err


def test_evaluate_with_a_model_of_another_stage_is_a_clear_error(tmp_path, rig, capsys):
    S = STAGES["init"]
    path = tmp_path / "init.pt"
    torch.save({n: network_record(m) for n, m in S(S.Model(), S.Loss(), RenderSettings(), rig).networks().items()},
               path)
    assert main(["evaluate", "--model", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "needs networks ['l0', 'initializer', 'lighting', 'svbrdf']" in capsys.readouterr().err
