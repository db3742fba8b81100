"""The bench commands end to end on the simulated rig: `mitsvbrdf capture` and `mitsvbrdf calibrate`."""

import json

import numpy as np
import pytest

import mitsvbrdf as ms
from mitsvbrdf import imageio
from mitsvbrdf.capture.camera import CameraModel, checkerboard_image
from mitsvbrdf.capture.display import write_display_model
from mitsvbrdf.cli import main
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.rig import DEFAULT_SCENE

SCENE = DEFAULT_SCENE
MATERIAL = DEFAULT_MATERIAL
SIM = ["--simulate", str(MATERIAL), "--resolution", "16", "--spp", "4", "--quiet"]


def test_simulated_capture_session_writes_the_reconstruction(tmp_path):
    assert main(["capture", "--out", str(tmp_path / "s"), *SIM]) == 0
    m = json.loads((tmp_path / "s" / "session.json").read_text())
    assert m["done"] and (tmp_path / "s" / "maps.exr").is_file()
    assert ms.SVBRDF.load(tmp_path / "s" / "maps.exr").resolution == (16, 16)


def test_capture_into_an_existing_session_needs_resume(tmp_path, capsys):
    assert main(["capture", "--out", str(tmp_path), *SIM]) == 0
    assert main(["capture", "--out", str(tmp_path), *SIM]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["capture", "--out", str(tmp_path), "--resume", *SIM]) == 0


@pytest.mark.parametrize("change", [["--gain", "7"], ["--seed", "5"], ["--spp", "2"]])
def test_capture_resume_with_another_frame_setting_is_one_line(tmp_path, capsys, change):
    assert main(["capture", "--out", str(tmp_path), *SIM]) == 0
    capsys.readouterr()
    assert main(["capture", "--out", str(tmp_path), "--resume", *SIM, *change]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot resume with different settings" in err[0] and change[0][2:] in err[0]


def test_capture_resume_captures_a_deleted_raw_frame_again(tmp_path, capsys):
    assert main(["capture", "--out", str(tmp_path), *SIM]) == 0
    (tmp_path / "raw" / "L1_e0.exr").unlink()
    assert main(["capture", "--out", str(tmp_path), "--resume", *SIM]) == 0
    assert "raw/L1_e0.exr (missing)" in capsys.readouterr().out
    assert (tmp_path / "raw" / "L1_e0.exr").is_file()


def test_calibrate_display_writes_the_simulated_truth_into_the_scene(tmp_path, capsys):
    truth = write_display_model(SCENE, tmp_path / "truth.xml", gamma=2.2, intensity=(2.0, 1.8, 1.5))
    out = tmp_path / "calibrated.xml"
    assert main(["calibrate", "display", "--simulate", "target", "--truth-scene", str(truth), "--out", str(out),
                 "--resolution", "12", "--spp", "64"]) == 0
    display = ms.Rig.from_scene(out).display
    assert display.gamma == pytest.approx(2.2, abs=0.02)
    np.testing.assert_allclose(display.intensity, (2.0, 1.8, 1.5), rtol=0.02)
    assert json.loads(capsys.readouterr().out)["step"] == "display"


def test_calibrate_intrinsics_from_a_folder_of_checkerboard_photos(tmp_path):
    rig = ms.Rig.from_scene(SCENE)
    cam = CameraModel.from_rig(rig)
    views = tmp_path / "views"
    views.mkdir()
    for i, (axis, deg) in enumerate([((1, 0, 0), 30), ((0, 1, 0), -30), ((1, 1, 0), 30), ((1, -1, 0), -30)]):
        from scipy.spatial.transform import Rotation

        board = np.eye(4)
        board[:3, :3] = Rotation.from_rotvec(np.radians(deg) * np.array(axis) / np.linalg.norm(axis)).as_matrix()
        imageio.write_png(views / f"v{i}.png", checkerboard_image(cam, board, (7, 9), 0.005, supersample=8), bits=16)
    out = tmp_path / "cal.xml"
    assert main(["calibrate", "intrinsics", "--views", str(views), "--inner", "6x8", "--square", "0.005",
                 "--out", str(out)]) == 0
    assert ms.Rig.from_scene(out).camera_fov == pytest.approx(rig.camera_fov, rel=0.01)


def test_calibrate_intrinsics_without_enough_photos_is_refused(tmp_path, capsys):
    assert main(["calibrate", "intrinsics", "--views", str(tmp_path), "--out", str(tmp_path / "x.xml")]) == 2
    assert "at least 3" in capsys.readouterr().err


def test_ctrl_c_during_a_capture_exits_130_and_says_how_to_resume(tmp_path, capsys, monkeypatch):
    from mitsvbrdf.capture import session

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(session.CaptureSession, "run", interrupted)
    assert main(["capture", "--out", str(tmp_path / "s"), *SIM]) == 130
    assert "rerun with --resume" in capsys.readouterr().err
