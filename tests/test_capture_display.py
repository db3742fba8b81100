"""LCD calibration from simulated captures: drive curve and emission decay, written to a scene."""

import numpy as np
import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.capture.display import diffuse_target, fit_decay_power, fit_gamma, write_display_model
from mitsvbrdf.rig import DEFAULT_SCENE

SCENE = DEFAULT_SCENE


def capture(rig, pattern, size=12):
    with torch.no_grad():
        return ms.render(diffuse_target(rig, size), pattern, rig, lobes="diffuse")[0]


def test_gamma_is_recovered_from_grey_levels(rig):
    truth = rig.with_display(gamma=2.2)
    drives = np.linspace(0.1, 1.0, 6)
    means = [float(capture(truth, torch.full((1, 3, 32, 32), d), size=4).mean()) for d in drives]
    assert fit_gamma(drives, means) == pytest.approx(2.2, abs=0.01)


def test_decay_exponent_is_recovered_from_a_white_capture(rig):
    truth = rig.with_display(decay_cos_power=1.5)
    white = capture(truth, torch.ones(1, 3, 32, 32))[0].permute(1, 2, 0).numpy()
    white = white * 3.7  # unknown albedo and intensity: only the shape counts
    assert fit_decay_power(white, rig) == pytest.approx(1.5, abs=0.05)


def test_calibration_written_into_a_scene_is_what_the_rig_reads(tmp_path):
    out = write_display_model(SCENE, tmp_path / "calibrated.xml", gamma=2.2, decay_cos_power=1.5)
    rig = ms.Rig.from_scene(out)
    assert rig.display.gamma == pytest.approx(2.2) and rig.display.decay_cos_power == pytest.approx(1.5)
    assert "The default capture rig" in out.read_text()  # the file's comments survive
    again = write_display_model(out, tmp_path / "twice.xml", gamma=1.8)
    assert ms.Rig.from_scene(again).display.gamma == pytest.approx(1.8)


def test_too_few_grey_levels_are_refused():
    with pytest.raises(ValueError, match="at least 2 grey levels"):
        fit_gamma(np.array([0.01, 0.5]), np.array([0.0, 0.2]))
