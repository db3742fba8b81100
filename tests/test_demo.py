"""The demo (main job) and the evaluate command on a tiny configuration."""

import json

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.acquisition import SETTINGS_KEY, AcquisitionSettings
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


def test_demo_records_the_training_grid_and_the_transfer_mode_it_reconstructed_with(tmp_path, networks):
    recs = torch.load(networks, weights_only=True)
    recs[SETTINGS_KEY] = AcquisitionSettings(resolution=16).record()  # trained on a coarser grid
    coarse = tmp_path / "coarse.pt"
    torch.save(recs, coarse)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--networks", str(coarse), "--resolution", "32", "--spp", "1",
                 "--transfer", "coarse", "--quiet"]) == 0
    rec = json.loads((out / "demo.json").read_text())
    assert (rec["transfer"], rec["trained_resolution"]) == ("coarse", 16)
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


def _export(stage, path):
    torch.save({n: network_record(m) for n, m in stage.networks().items()}, path)
    return str(path)


def test_evaluate_scores_every_kind_of_baseline_and_adaptive_variant(tmp_path, networks, rig):
    S, A = STAGES["fixed"], STAGES["stage2"]
    runs = {
        "optimized": S(S.Model(patterns="random", learn_patterns=True, svbrdf_width=4), S.Loss(), RenderSettings(), rig),
        "lpl": S(S.Model(patterns="uniform", learn_patterns=True, svbrdf_width=4), S.Loss(), RenderSettings(), rig),
        "flash": S(S.Model(light="flash", svbrdf_width=4), S.Loss(), RenderSettings(), rig),
    }
    args = ["evaluate", "--model", str(networks), "--data", "procedural", "--n", "1", "--size", "32", "--spp", "2",
            "--out", str(tmp_path / "eval"), "--quiet"]
    for name, stage in runs.items():
        args += ["--baseline", f"{name}={_export(stage, tmp_path / f'{name}.pt')}"]
    nospec = A(A.Model(lighting_width=4, svbrdf_width=4, use_spec=False), A.Loss(), RenderSettings(), rig)
    args += ["--adaptive", f"nospec={_export(nospec, tmp_path / 'nospec.pt')}",
             "--uniform-lpdf", f"diff-init={networks}"]
    assert main(args) == 0
    table = (tmp_path / "eval" / "summary.md").read_text()
    for name in ("adaptive", "nospec", "diff-init", "optimized", "lpl", "flash"):
        assert f"| {name} |" in table, name


def test_evaluate_with_a_malformed_or_foreign_baseline_is_a_clear_error(tmp_path, networks, capsys):
    base = ["evaluate", "--model", str(networks), "--n", "1", "--size", "32", "--out", str(tmp_path / "o"), "--quiet"]
    assert main(base + ["--baseline", "monograd"]) == 2
    assert "--baseline expects NAME=NETWORKS.pt" in capsys.readouterr().err
    assert main(base + ["--baseline", f"x={networks}"]) == 2  # an adaptive export is not a baseline
    assert "a baseline needs networks 'svbrdf' and 'patterns' (or 'flash')" in capsys.readouterr().err


def test_held_out_procedural_materials_are_named_by_their_index():
    from mitsvbrdf.evaluation import load_materials
    from mitsvbrdf.data.procedural import generate
    from mitsvbrdf.training.config import TEST_SEED_BASE

    mats = load_materials("procedural", 16, 3)
    assert [m.name for m in mats] == [f"procedural:{TEST_SEED_BASE}:{i}" for i in range(3)]
    assert torch.equal(mats[2].diffuse, generate(3, size=16, seed=TEST_SEED_BASE)[2].diffuse)


def test_evaluate_with_a_negative_figure_count_is_a_clear_error(tmp_path, networks, capsys):
    assert main(["evaluate", "--model", str(networks), "--figures", "-1", "--out", str(tmp_path / "o"),
                 "--quiet"]) == 2
    assert "--figures must be >= 0" in capsys.readouterr().err
