"""Bad values on the command line: one line ``mitsvbrdf: error: ...`` naming the value, exit 2,
before any work starts, and nothing left behind (issue 17; the table is in docs/reliability.md).

Every case runs in an empty folder that holds only the inputs the case made; afterwards the folder
must hold exactly those again.
"""

from pathlib import Path

import math

import numpy as np
import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf import patterns as pt
from mitsvbrdf.cli import main
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.errors import ImageError, MaterialError, MitsvbrdfError, PatternError
from mitsvbrdf.rig import DEFAULT_SCENE

ROOT = Path(__file__).resolve().parents[1]
SCENE = str(DEFAULT_SCENE)
MATERIAL = str(DEFAULT_MATERIAL)
NETWORKS = str(ROOT / "mitsvbrdf" / "weights" / "networks.pt")


def simulate(*extra, scene=SCENE):
    return ["simulate", scene, "--material", MATERIAL, "--out", "out", "--quiet", "--resolution", "8", *extra]


def train(setting):
    return ["train", str(ROOT / "train" / "init-small.toml"), "--out", "run", "--quiet", "--set", setting]


def capture(*extra):
    return ["capture", "--out", "session", "--simulate", MATERIAL, "--resolution", "16", "--spp", "1", "--quiet",
            *extra]


def calibrate(step, *extra):
    return ["calibrate", step, "--out", "cal.xml", "--simulate", "target", "--resolution", "8", "--spp", "1", *extra]


def _a_file(tmp):
    (tmp / "afile").write_text("not a folder")


def _junk(name):
    def make(tmp):
        (tmp / name).write_text("junk")
    return make


def _a_camera_folder(tmp):
    (tmp / "frames").mkdir()


def _empty_patterns(tmp):
    np.save(tmp / "empty.npy", np.zeros((0, 3, 32, 32), np.float32))


def _a_folder(tmp):
    (tmp / "cal.xml").mkdir()


def _scene(old, new):
    """A copy of the default scene with one edit, as rig.xml."""
    def make(tmp):
        text = Path(SCENE).read_text()
        assert old in text
        (tmp / "rig.xml").write_text(text.replace(old, new, 1))
    return make


ZERO_LCD = _scene('<scale x="0.045" y="0.045"/>', '<scale x="0" y="0"/>')
DARK_LCD = _scene('<float name="intensity" value="1.0"/>', '<float name="intensity" value="0"/>')
NEGATIVE_LCD = _scene('<float name="intensity" value="1.0"/>', '<float name="intensity" value="-1"/>')


# (id, argv, what the message names, a function making the case's inputs in the folder)
CASES = [
    ("simulate-resolution-0", simulate("--resolution", "0"), "--resolution", None),
    ("simulate-resolution-negative", simulate("--resolution", "-5"), "--resolution", None),
    ("simulate-spp-0", simulate("--spp", "0"), "--spp", None),
    ("simulate-seed-negative", simulate("--seed", "-1"), "--seed", None),
    ("simulate-seed-huge", simulate("--seed", str(10 ** 20)), "--seed", None),
    ("simulate-cell-order-0", simulate("--method", "reference", "--cell-order", "0"), "--cell-order", None),
    ("simulate-lobe-grid-negative", simulate("--method", "reference", "--lobe-grid", "-1"), "--lobe-grid", None),
    ("simulate-out-is-a-file", simulate("--out", "afile"), "is a file", _a_file),
    ("simulate-out-under-a-file", simulate("--out", "afile/sub"), "which is a file", _a_file),
    ("simulate-empty-pattern-file", simulate("--patterns", "empty.npy"), "no patterns", _empty_patterns),
    ("simulate-pattern-file-not-torch", simulate("--patterns", "junk.pt"), "cannot read patterns", _junk("junk.pt")),
    ("demo-networks-not-a-network-file", ["demo", "--networks", SCENE, "--out", "demo", "--quiet"],
     "cannot read a networks", None),
    ("simulate-zero-size-lcd", simulate(scene="rig.xml"), "positive size", ZERO_LCD),
    ("simulate-zero-intensity", simulate(scene="rig.xml"), "intensity", DARK_LCD),
    ("simulate-negative-intensity", simulate(scene="rig.xml"), "intensity", NEGATIVE_LCD),
    ("demo-zero-size-lcd", ["demo", "--scene", "rig.xml", "--out", "demo", "--quiet"], "positive size", ZERO_LCD),
    ("calibrate-display-zero-size-lcd", calibrate("display", "--scene", "rig.xml"), "positive size", ZERO_LCD),
    ("train-out-is-a-file", ["train", str(ROOT / "train" / "init-small.toml"), "--out", "afile", "--quiet"],
     "is a file", _a_file),
    ("train-out-under-a-file", ["train", str(ROOT / "train" / "init-small.toml"), "--out", "afile/run", "--quiet"],
     "which is a file", _a_file),
    ("simulate-quadrature-beyond-its-memory-bound", simulate("--method", "reference", "--lobe-grid", "100000"),
     "points per texel", None),
    ("train-data-size-0", train("data.size=0"), "data.size", None),
    ("train-lr-infinite", train("train.lr=inf"), "train.lr", None),
    ("train-grad-clip-nan", train("train.grad_clip=nan"), "train.grad_clip", None),
    ("train-no-materials", train("data.length=0"), "data.length", None),
    ("train-negative-shot-noise", train("render.noise.shot=-1"), "render.noise.shot", None),
    ("evaluate-size-not-a-multiple", ["evaluate", "--model", NETWORKS, "--size", "20", "--n", "1", "--out", "ev",
                                      "--quiet"], "multiple of 8", None),
    ("evaluate-size-0", ["evaluate", "--model", NETWORKS, "--size", "0", "--out", "ev", "--quiet"], "--size", None),
    ("evaluate-no-procedural-materials", ["evaluate", "--model", NETWORKS, "--n", "0", "--out", "ev", "--quiet"],
     "--n", None),
    ("demo-resolution-not-a-multiple", ["demo", "--resolution", "20", "--out", "demo", "--quiet"], "multiple of 8",
     None),
    ("demo-spp-0", ["demo", "--spp", "0", "--out", "demo", "--quiet"], "--spp", None),
    ("demo-seed-beyond-the-capture-seeds", ["demo", "--seed", str(2 ** 32 // 100), "--out", "demo", "--quiet"],
     "--seed", None),
    ("pca-count-0", ["patterns", "pca", "--count", "0", "--out", "p.npy"], "--count", None),
    ("pca-stride-0", ["patterns", "pca", "--stride", "0", "--out", "p.npy"], "--stride", None),
    ("pca-fewer-materials-than-patterns", ["patterns", "pca", "--n", "3", "--count", "5", "--out", "p.npy"], "--n",
     None),
    ("materials-preview-no-materials", ["materials", "preview", "--n", "0", "--out", "sheet.png", "--quiet"], "--n",
     None),
    ("materials-preview-out-is-a-folder", ["materials", "preview", "--n", "1", "--out", "cal.xml", "--quiet"],
     "is a folder", _a_folder),
    ("scene-out-is-a-folder", ["scene", "--out", "cal.xml"], "is a folder", _a_folder),
    ("scene-out-under-a-file", ["scene", "--out", "afile/rig.xml"], "which is a file", _a_file),
    ("capture-exposures-words", capture("--exposures", "abc"), "--exposures", None),
    ("capture-exposures-not-positive", capture("--exposures", "0,-1"), "--exposures", None),
    ("capture-gain-0", capture("--gain", "0"), "--gain", None),
    ("capture-camera-without-its-response", ["capture", "--out", "session", "--camera-folder", "frames", "--display",
                                             "shown.png", "--resolution", "16", "--quiet"], "response",
     _a_camera_folder),
    ("capture-controller-unreachable", capture("--controller", "socket://127.0.0.1:1"), "--controller", None),
    ("capture-resolution-not-a-multiple", capture("--resolution", "20"), "multiple of 8", None),
    ("calibrate-response-one-exposure", calibrate("response", "--exposures", "0.5"), "at least 2", None),
    ("calibrate-response-one-exposure-twice", calibrate("response", "--exposures", "0.5,0.5"), "at least 2", None),
    ("calibrate-response-narrow-bracket", calibrate("response", "--exposures", "0.5,0.6"), "extend the exposures",
     None),
    ("calibrate-out-is-a-folder", calibrate("response", "--exposures", "0.1,1"), "is a folder", _a_folder),
    ("calibrate-albedo-0", calibrate("display", "--albedo", "0"), "--albedo", None),
    ("calibrate-without-a-camera", ["calibrate", "display", "--out", "cal.xml"], "--camera-folder", None),
    ("calibrate-intrinsics-views-missing", ["calibrate", "intrinsics", "--out", "cal.xml", "--views", "nowhere"],
     "--views", None),
    ("calibrate-intrinsics-square-0", ["calibrate", "intrinsics", "--out", "cal.xml", "--views", ".", "--square", "0"],
     "--square", None),
    ("calibrate-intrinsics-inner-1", ["calibrate", "intrinsics", "--out", "cal.xml", "--views", ".", "--inner", "1x8"],
     "--inner", None),
]


@pytest.mark.parametrize("argv,words,make", [pytest.param(a, w, m, id=i) for i, a, w, m in CASES])
def test_bad_value_is_one_line_exit_2_and_leaves_nothing_behind(tmp_path, monkeypatch, capsys, argv, words, make):
    monkeypatch.chdir(tmp_path)
    if make is not None:
        make(tmp_path)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mitsvbrdf: error: "), err
    assert words in err[0]
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


# ---- the same contract in the Python API: a MitsvbrdfError (a ValueError) instead of a wrong result


@pytest.mark.parametrize("bad_map", ["normal", "roughness"])
def test_importance_refuses_nan_maps(rig, bad_map):
    m = ms.SVBRDF.constant(size=4)
    maps = {"normal": m.normal.clone(), "roughness": m.roughness.clone()}
    maps[bad_map][0, :, 1, 2] = math.nan
    with pytest.raises(MaterialError, match=bad_map):
        ms.importance(maps["normal"], maps["roughness"], rig)


@pytest.mark.parametrize("bad,words", [("roughness", "roughness must lie in"), ("normal", "unit vectors")])
def test_importance_refuses_maps_outside_their_range(rig, bad, words):
    # roughness 5 or a zero normal gave an L_pdf without complaint
    m = ms.SVBRDF.constant(size=4)
    normal, roughness = m.normal.clone(), m.roughness.clone()
    if bad == "roughness":
        roughness[0, 0, 0, 0] = 5.0
    else:
        normal[0, :, 0, 0] = 0.0
    with pytest.raises(MaterialError, match=words):
        ms.importance(normal, roughness, rig)


@pytest.mark.parametrize("method", ["reference", "ltc"])
def test_render_refuses_an_empty_pattern_set(rig, method):
    with pytest.raises(PatternError, match="no pattern"):
        ms.render(ms.SVBRDF.constant(size=4), torch.zeros(0, 3, *rig.lcd_cells), rig, method=method)


def test_importance_refuses_a_texel_stride_below_1(rig):
    m = ms.SVBRDF.constant(size=4)
    with pytest.raises(MitsvbrdfError, match="texel_stride"):
        ms.importance(m.normal, m.roughness, rig, texel_stride=0)


@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_separate_specular_refuses_non_finite_images(rig, value):
    images = torch.rand(2, 3, 4, 4)
    images[1, 0, 2, 2] = value
    with pytest.raises(ImageError, match="NaN/Inf"):
        ms.separate_specular(images, pt.random(n=2), rig)


@pytest.mark.parametrize("kwargs,words", [(dict(spp=0), "spp"), (dict(seed=-1), "seed"), (dict(seed=2 ** 32), "seed"),
                                          (dict(spp=2 ** 26), "one pass")])
def test_mitsuba_render_checks_its_numbers_before_loading_the_scene(rig, kwargs, words):
    with pytest.raises(MitsvbrdfError, match=words):
        ms.render(ms.SVBRDF.constant(size=8), pt.uniform(), rig, method="mitsuba", **kwargs)


def test_pca_of_no_patterns_is_refused():
    with pytest.raises(PatternError, match="count"):
        pt.pca_patterns(torch.rand(6, 1, 32, 32), n=0)


def test_simulation_record_reports_the_measured_radiance_of_a_black_capture(tmp_path):
    # It said 1.0 (the tone-mapping fallback) for black images.
    np.save(tmp_path / "black.npy", np.zeros((1, 3, 32, 32), np.float32))
    assert main(["simulate", SCENE, "--material", MATERIAL, "--patterns", str(tmp_path / "black.npy"), "--method",
                 "reference", "--resolution", "4", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    import json
    assert json.loads((tmp_path / "out" / "simulation.json").read_text())["radiance_p99_5"] == 0.0


def test_ctrl_c_in_any_command_exits_130_with_one_line(monkeypatch, capsys):
    import mitsvbrdf.cli as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "cmd_patterns_pca", interrupted)
    assert main(["patterns", "pca", "--out", "p.npy"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["mitsvbrdf: interrupted"]


def test_evaluate_refuses_a_material_size_its_networks_cannot_take_before_making_the_folder(rig, tmp_path):
    from mitsvbrdf.acquisition import load_adaptive
    from mitsvbrdf.evaluation import evaluate, simulated

    method = simulated(load_adaptive(NETWORKS, rig), spp=1)
    with pytest.raises(MitsvbrdfError, match="multiple of 8"):
        evaluate({"adaptive": method}, [ms.SVBRDF.constant(size=20)], rig, tmp_path / "ev", progress=False)
    assert not (tmp_path / "ev").exists()
