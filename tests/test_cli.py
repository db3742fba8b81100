"""`mitsvbrdf simulate` writes the capture and reports bad input as a one-line error; `mitsvbrdf scene`
copies the default rig out; `mitsvbrdf patterns pca` writes a pattern group."""

import json

import numpy as np
import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import imageio
from mitsvbrdf.cli import main
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.rig import DEFAULT_SCENE

SCENE = DEFAULT_SCENE
EXAMPLE = DEFAULT_MATERIAL


def test_simulate_writes_images_patterns_and_a_record(tmp_path):
    rc = main(["simulate", str(SCENE), "--material", str(EXAMPLE), "--patterns", "monograd",
               "--out", str(tmp_path), "--resolution", "16", "--method", "reference", "--quiet"])
    assert rc == 0
    rec = json.loads((tmp_path / "simulation.json").read_text())
    assert rec["resolution"] == [16, 16] and len([f for f in rec["files"] if f.endswith(".exr")]) == 5
    for f in rec["files"]:
        assert (tmp_path / f).is_file()
    img = torch.from_numpy(imageio.read_image(tmp_path / "image_01.exr")).permute(2, 0, 1)
    m = ms.SVBRDF.load(tmp_path / "material.png")
    want = ms.render(m, ms.pattern_family("monograd")[1:2], ms.Rig.from_scene(SCENE))[0, 0]
    torch.testing.assert_close(img, want, rtol=0.03, atol=1e-4)  # material.png is 8-bit


@pytest.mark.mitsuba
def test_simulate_renders_through_the_scene_plugins_by_default(tmp_path):
    from mitsvbrdf import backend
    if backend.find_libllvm() is None:
        pytest.skip("no libLLVM >= 16 for the LLVM backend")
    rc = main(["simulate", str(SCENE), "--material", str(EXAMPLE), "--patterns", "uniform",
               "--out", str(tmp_path), "--resolution", "8", "--spp", "4096", "--quiet"])
    assert rc == 0
    rec = json.loads((tmp_path / "simulation.json").read_text())
    assert rec["method"] == "mitsuba" and rec["settings"]["spp"] == 4096
    img = torch.from_numpy(imageio.read_image(tmp_path / "image_00.exr")).permute(2, 0, 1)
    m = ms.SVBRDF.load(tmp_path / "material.png")
    want = ms.render(m, ms.pattern_family("uniform"), ms.Rig.from_scene(SCENE))[0, 0]
    assert ((img - want).norm() / want.norm()).item() < 0.05


def test_simulate_reports_a_missing_material_as_an_error(tmp_path, capsys):
    rc = main(["simulate", str(SCENE), "--material", str(tmp_path / "none.png"), "--out", str(tmp_path), "--quiet"])
    assert rc == 2
    assert "none.png" in capsys.readouterr().err


def test_simulate_reports_a_bad_pattern_name(tmp_path, capsys):
    rc = main(["simulate", str(SCENE), "--material", str(EXAMPLE), "--patterns", "sunset",
               "--out", str(tmp_path), "--resolution", "8", "--quiet"])
    assert rc == 2 and "sunset" in capsys.readouterr().err


def test_patterns_pca_writes_a_group_of_valid_patterns(tmp_path):
    from mitsvbrdf.cli import main

    out = tmp_path / "pca.npy"
    assert main(["patterns", "pca", "--out", str(out), "--n", "6", "--size", "16", "--stride", "4"]) == 0
    p = np.load(out)
    assert p.shape == (5, 3, 32, 32) and p.min() >= 0 and p.max() <= 1


def test_scene_copies_the_default_rig_out(tmp_path):
    out = tmp_path / "bench" / "rig.xml"
    assert main(["scene", "--out", str(out)]) == 0
    assert out.read_bytes() == DEFAULT_SCENE.read_bytes()


def test_scene_does_not_overwrite_an_existing_file(tmp_path, capsys):
    out = tmp_path / "calibrated.xml"
    out.write_text("<scene/>")
    assert main(["scene", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "<scene/>"
