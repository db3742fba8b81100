"""Capture sessions on the simulated rig: devices, HDR merging, every frame on disk, resume."""

import json

import numpy as np
import pytest
import torch

from mitsvbrdf import imageio
from mitsvbrdf.capture.devices import DeviceError, FileDropCamera, ImageFileDisplay, SimulatedRig, check_pattern
from mitsvbrdf.capture.hdr import Response
from mitsvbrdf.capture.session import BracketCapture, CaptureSession, SessionError, merge_frames
from mitsvbrdf.acquisition import DEFAULT_NETWORKS, load_adaptive
from mitsvbrdf.render import render
from mitsvbrdf.sensor import SensorNoise

from conftest import textured_material

SIZE = 24
EXPOSURES = (0.5, 2.0, 8.0)


def camera(rig, **kw):
    """A noisy 8-bit camera with a gamma response on the textured material."""
    args = dict(method="mitsuba", spp=2, seed=3, gain=4.0, noise=SensorNoise(shot=1e-3, read=2e-3),
                response=Response.gamma(2.2))
    args.update(kw)
    return SimulatedRig(textured_material(SIZE, seed=1), rig, **args)


def bracket(sim, exposures=EXPOSURES):
    return BracketCapture(sim, sim, exposures, response=sim.response)


@pytest.fixture(scope="module")
def pipeline(rig):
    return load_adaptive(DEFAULT_NETWORKS, rig)


class FailingCamera:
    """Passes frames through until ``fail_after`` frames, then the cable is 'pulled'."""

    def __init__(self, inner, fail_after):
        self.inner, self.left = inner, fail_after
        self.linear, self.rectified = inner.linear, inner.rectified

    def capture(self, exposure):
        if self.left == 0:
            raise DeviceError("camera disconnected")
        self.left -= 1
        return self.inner.capture(exposure)

    def frame_settings(self):  # the same camera, on a bad cable
        return self.inner.frame_settings()


# ---- devices ---------------------------------------------------------------------------------------


def test_simulated_linear_frame_is_the_render_times_gain_and_exposure(rig):
    sim = SimulatedRig(textured_material(SIZE, seed=1), rig, method="reference", gain=0.5)
    pattern = np.full((3, 32, 32), 0.7, np.float32)
    sim.show(pattern)
    expected = render(textured_material(SIZE, seed=1), torch.from_numpy(pattern)[None], rig)[0, 0].permute(1, 2, 0)
    np.testing.assert_allclose(sim.capture(2.0), np.clip(expected.numpy(), 0, 1), rtol=1e-5, atol=1e-7)


def test_simulated_frames_are_repeatable_per_pattern_and_exposure(rig):
    sim = camera(rig)
    sim.show(np.full((3, 32, 32), 0.5, np.float32))
    a, b, c = sim.capture(1.0), sim.capture(1.0), sim.capture(2.0)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_simulated_camera_saturates_and_quantises(rig):
    sim = camera(rig, noise=None, response=Response.gamma(2.2, levels=16))
    sim.show(np.ones((3, 32, 32), np.float32))
    f = sim.capture(1000.0)
    assert f.max() == 1.0 and np.allclose(f * 15, np.round(f * 15))


def test_capture_before_any_pattern_is_shown_is_an_error(rig):
    with pytest.raises(DeviceError, match="show"):
        camera(rig).capture(1.0)


def test_patterns_of_the_wrong_shape_or_range_are_refused():
    with pytest.raises(ValueError, match=r"\(3, 32, 32\)"):
        check_pattern(np.zeros((3, 16, 16)), (32, 32))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        check_pattern(np.full((3, 32, 32), 1.5), (32, 32))


def test_file_drop_camera_reads_the_frame_its_trigger_produced(tmp_path):
    imageio.write_png(tmp_path / "old.png", np.zeros((4, 4, 3)))  # present before: not a new frame
    frame = np.random.default_rng(0).random((4, 6, 3)).astype(np.float32)

    def tether(exposure):
        imageio.write_exr(tmp_path / f"frame_{exposure:g}.exr", frame * exposure)

    cam = FileDropCamera(tmp_path, trigger=tether, timeout=2, linear=True, rectified=True)
    np.testing.assert_allclose(cam.capture(0.5), frame * 0.5, rtol=1e-6)


def test_file_drop_camera_times_out_with_a_clear_error(tmp_path):
    cam = FileDropCamera(tmp_path, timeout=0.2)
    with pytest.raises(DeviceError, match="no new frame appeared"):
        cam.capture(0.01)


def test_image_file_display_writes_the_pattern(tmp_path):
    shown = []
    d = ImageFileDisplay(tmp_path / "lcd.png", on_show=shown.append)
    pattern = np.zeros((3, 32, 32), np.float32)
    pattern[0, 3, 5] = 1.0
    d.show(pattern)
    img = imageio.read_image(tmp_path / "lcd.png")
    assert shown == [tmp_path / "lcd.png"] and img[3, 5, 0] == 1.0 and img.sum() == 1.0


# ---- HDR merging ------------------------------------------------------------------------------------


def test_linear_merge_of_one_frame_is_value_over_exposure():
    f = np.random.default_rng(1).random((1, 5, 5, 3)) * 0.9
    rad, counts = merge_frames(f, np.array([0.25]), None)
    np.testing.assert_allclose(rad, f[0] / 0.25, rtol=1e-6)
    assert counts == {"saturated": 0, "dark": 0}


def test_bracket_recovers_radiance_over_three_decades(rig):
    radiance = np.geomspace(1e-3, 1.0, 64 * 3).reshape(8, 8, 3)
    response = Response.gamma(2.2, levels=1024)
    times = np.array([0.5, 4.0, 32.0, 256.0])
    frames = np.stack([response.pixel_value(radiance * t) for t in times])
    rad, counts = merge_frames(frames, times, response)
    assert counts["saturated"] == 0
    np.testing.assert_allclose(rad, radiance, rtol=0.02)


def test_samples_saturated_in_every_frame_are_counted_and_bounded():
    f = np.ones((2, 2, 2, 3))
    rad, counts = merge_frames(f, np.array([1.0, 2.0]), None)
    assert counts["saturated"] == 12 and np.allclose(rad, 1.0)


# ---- sessions ------------------------------------------------------------------------------------------


def test_session_reconstruction_equals_the_in_memory_pipeline(rig, pipeline, tmp_path):
    acq = CaptureSession(tmp_path / "s", pipeline, bracket(camera(rig))).run(progress=False)
    mem = pipeline.acquire(bracket(camera(rig)))
    assert torch.equal(acq.patterns, mem.patterns)
    assert torch.equal(acq.images, mem.images)
    assert torch.equal(acq.svbrdf.encoded(), mem.svbrdf.encoded())


def test_session_writes_every_frame_pattern_and_the_maps(rig, pipeline, tmp_path):
    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    m = json.loads((tmp_path / "session.json").read_text())
    assert m["done"] and sorted(m["steps"]) == ["L0", "L1", "L2", "L3", "L4"]
    for step in m["steps"].values():
        assert len(step["frames"]) == len(EXPOSURES)
        for rel in [*step["frames"].values(), step["radiance"], step["pattern"]]:
            assert (tmp_path / rel).is_file()
    for name in ("maps.exr", "maps.png", "patterns.png", "images.png", "lpdf.npy"):
        assert (tmp_path / name).is_file()
    assert not list(tmp_path.rglob(".tmp-*"))


@pytest.mark.parametrize("fail_after", [1, 7])
def test_a_pulled_cable_loses_no_frame_and_resume_completes_the_same_session(rig, pipeline, tmp_path, fail_after):
    whole = CaptureSession(tmp_path / "whole", pipeline, bracket(camera(rig))).run(progress=False)
    s = tmp_path / "cut"
    sim = camera(rig)
    with pytest.raises(DeviceError, match="disconnected"):
        CaptureSession(s, pipeline, BracketCapture(sim, FailingCamera(sim, fail_after), EXPOSURES,
                                                   response=sim.response)).run(progress=False)
    m = json.loads((s / "session.json").read_text())
    assert sum(len(st["frames"]) for st in m["steps"].values()) == fail_after
    rest = camera(rig)
    acq = CaptureSession(s, pipeline, bracket(rest)).run(resume=True, progress=False)
    assert rest.frames_taken == 5 * len(EXPOSURES) - fail_after
    assert torch.equal(acq.svbrdf.encoded(), whole.svbrdf.encoded())


def test_a_finished_session_is_not_overwritten(rig, pipeline, tmp_path):
    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    with pytest.raises(SessionError, match="--resume"):
        CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)


def test_resume_with_other_settings_is_refused(rig, pipeline, tmp_path):
    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    with pytest.raises(SessionError, match="exposures"):
        CaptureSession(tmp_path, pipeline, bracket(camera(rig), (1.0,))).run(resume=True, progress=False)


def test_resume_with_other_acquisition_settings_is_refused(rig, pipeline, tmp_path):
    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    uniform = load_adaptive(DEFAULT_NETWORKS, rig, lpdf_from="uniform")  # the same weights, other patterns
    with pytest.raises(SessionError, match="acquisition"):
        CaptureSession(tmp_path, uniform, bracket(camera(rig))).run(resume=True, progress=False)


def test_resume_with_another_gain_is_refused(rig, pipeline, tmp_path):
    # The gain was not recorded: L0 stayed, L1-L4 came out brighter.
    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    with pytest.raises(SessionError, match="camera.gain: 4.0 then, 8.0 now"):
        CaptureSession(tmp_path, pipeline, bracket(camera(rig, gain=8.0))).run(resume=True, progress=False)


def test_every_written_file_is_recorded_with_its_size_and_checksum(rig, pipeline, tmp_path):
    import hashlib

    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    files = json.loads((tmp_path / "session.json").read_text())["files"]
    on_disk = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()} - {"session.json"}
    assert set(files) == on_disk
    for rel, rec in files.items():
        data = (tmp_path / rel).read_bytes()
        assert rec == {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def _delete(p):
    p.unlink()


def _truncate(p):
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _same_size_other_bytes(p):
    b = bytearray(p.read_bytes())
    b[-1] ^= 0xFF
    p.write_bytes(bytes(b))


@pytest.mark.parametrize("damage", [_delete, _truncate, _same_size_other_bytes],
                         ids=["deleted", "truncated", "altered"])
def test_a_damaged_raw_frame_is_captured_again_on_resume(rig, pipeline, tmp_path, damage):
    whole = CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    damage(tmp_path / "raw" / "L2_e1.exr")
    again = camera(rig)
    session = CaptureSession(tmp_path, pipeline, bracket(again))
    acq = session.run(resume=True, progress=False)
    assert again.frames_taken == 1
    assert [r.split(" ")[0] for r in session.recaptured] == ["raw/L2_e1.exr"]
    assert torch.equal(acq.svbrdf.encoded(), whole.svbrdf.encoded())  # the simulated frame is the same frame


@pytest.mark.parametrize("rel", ["radiance/L3.exr", "patterns/adaptive.npy", "lpdf.npy"])
def test_a_damaged_derived_file_is_recomputed_without_new_frames(rig, pipeline, tmp_path, rel):
    whole = CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    _truncate(tmp_path / rel)
    again = camera(rig)
    session = CaptureSession(tmp_path, pipeline, bracket(again))
    acq = session.run(resume=True, progress=False)
    assert again.frames_taken == 0 and session.recaptured == [f"{rel} (changed)"]
    assert torch.equal(acq.svbrdf.encoded(), whole.svbrdf.encoded())


def test_a_step_whose_pattern_file_changed_is_captured_again(rig, pipeline, tmp_path):
    CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(progress=False)
    np.save(tmp_path / "patterns" / "L1.npy", np.zeros((3, *rig.lcd_cells), np.float32))
    again = camera(rig)
    CaptureSession(tmp_path, pipeline, bracket(again)).run(resume=True, progress=False)
    assert again.frames_taken == len(EXPOSURES)


def test_resume_without_a_session_is_refused(rig, pipeline, tmp_path):
    with pytest.raises(SessionError, match="nothing to resume"):
        CaptureSession(tmp_path, pipeline, bracket(camera(rig))).run(resume=True, progress=False)


def test_a_camera_with_a_response_needs_it(rig):
    with pytest.raises(ValueError, match="response"):
        BracketCapture(camera(rig), camera(rig), EXPOSURES, response=None)


def test_a_raw_only_capture_needs_no_response_but_has_no_radiance(rig):
    sim = camera(rig)
    cap = BracketCapture(sim, sim, EXPOSURES, response=None, raw_only=True)
    frames = cap.bracket(np.ones((3, *rig.lcd_cells), np.float32))
    assert len(frames) == len(EXPOSURES) and not sim.linear
    with pytest.raises(ValueError, match="raw brackets only"):
        cap.radiance(frames)


# ---- sessions through a serial controller ------------------------------------------------------------

FAST = (0.002, 0.008)  # the fake controller really waits for each exposure


def triggered(rig, url, fail_after=None):
    from mitsvbrdf.capture.controller import SerialController
    from mitsvbrdf.capture.devices import TriggeredCamera

    sim = camera(rig, gain=1000.0)
    ctl = SerialController(url, timeout=0.3, retries=2, reconnect=2, reconnect_delay=0.05)
    return BracketCapture(sim, TriggeredCamera(sim, ctl), FAST, response=sim.response), ctl


def test_a_dropped_serial_connection_is_reconnected_and_no_trigger_is_doubled(rig, pipeline, tmp_path):
    from mitsvbrdf.capture.fake_controller import FakeControllerDevice

    device = FakeControllerDevice(disconnect_after=5, garbage_before_reply=1)
    port, _ = device.serve_tcp()
    cap, ctl = triggered(rig, f"socket://127.0.0.1:{port}")
    try:
        acq = CaptureSession(tmp_path, pipeline, cap).run(progress=False)
    finally:
        ctl.close()
        device.stop()
    assert ctl.stats["reconnects"] >= 1
    assert [name for _, name, _ in device.executed].count("TRIGGER") == 5 * len(FAST)
    sim = camera(rig, gain=1000.0)
    mem = pipeline.acquire(BracketCapture(sim, sim, FAST, response=sim.response))
    assert torch.equal(acq.svbrdf.encoded(), mem.svbrdf.encoded())


def test_a_controller_gone_for_good_stops_the_session_and_resume_finishes_it(rig, pipeline, tmp_path):
    from mitsvbrdf.capture.controller import ControllerError
    from mitsvbrdf.capture.fake_controller import FakeControllerDevice

    device = FakeControllerDevice()
    port, _ = device.serve_tcp()
    cap, ctl = triggered(rig, f"socket://127.0.0.1:{port}")
    n = {"frames": 0}
    device.on_trigger = lambda dev: n.update(frames=n["frames"] + 1) or (n["frames"] == 4 and dev.stop())
    try:
        with pytest.raises(ControllerError, match="127.0.0.1"):
            CaptureSession(tmp_path, pipeline, cap).run(progress=False)
    finally:
        ctl.close()
        device.stop()
    recorded = sum(len(s["frames"]) for s in json.loads((tmp_path / "session.json").read_text())["steps"].values())
    assert recorded in (3, 4)  # the frame in flight when the link died may or may not have been read
    device = FakeControllerDevice()
    port, _ = device.serve_tcp()
    cap, ctl = triggered(rig, f"socket://127.0.0.1:{port}")
    try:
        acq = CaptureSession(tmp_path, pipeline, cap).run(resume=True, progress=False)
    finally:
        ctl.close()
        device.stop()
    assert [name for _, name, _ in device.executed].count("TRIGGER") == 5 * len(FAST) - recorded
    sim = camera(rig, gain=1000.0)
    whole = CaptureSession(tmp_path / "whole", pipeline, BracketCapture(sim, sim, FAST, response=sim.response)).run(
        progress=False)
    assert torch.equal(acq.svbrdf.encoded(), whole.svbrdf.encoded())
