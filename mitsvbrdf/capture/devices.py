"""The devices of a capture bench, as small protocols, and their implementations.

* :class:`Display` shows one pattern, (3, h, w) drive values in [0, 1], on the LCD.
* :class:`Camera` takes one frame at an exposure time (seconds): (H, W, 3) float values in [0, 1]
  as the sensor delivers them. ``linear`` says whether those values are proportional to exposure
  (RAW) or went through a response curve; ``rectified`` whether the frame already lies on the
  sample's texel grid (row 0 at the sample's +y edge) or is a camera view to be rectified.
* A controller on a serial line (:mod:`.controller`) fires the shutter and moves gantries.

Implementations:

* :class:`SimulatedRig` — Display *and* Camera: renders the shown pattern on a known material
  through the scene file (Mitsuba plugins by default), then applies the camera: gain, sensor
  noise (shot + read), saturation, a response curve and quantisation. Frames are deterministic
  functions of (seed, pattern, exposure), so a resumed session sees the frames it would have seen.
* :class:`FileDropCamera` — frames appear as files in a folder, written by any tethering tool
  (gphoto2, a vendor SDK, ...), optionally after a trigger callback such as
  :func:`controller_trigger`.
* :class:`ImageFileDisplay` — writes each pattern as a PNG at the LCD's cell resolution (and
  calls an optional hook), for a viewer or a display program to pick up; :class:`WindowDisplay`
  shows it full-screen with matplotlib when a GUI backend is available.
"""

from __future__ import annotations

import time
import zlib
from pathlib import Path
from typing import Callable, Protocol, runtime_checkable

import numpy as np
import torch

from .. import imageio
from ..errors import MitsvbrdfError
from ..render import render
from ..rig import Rig
from ..sensor import SensorNoise
from ..svbrdf import SVBRDF
from .hdr import Response


class DeviceError(MitsvbrdfError):
    """A device did not deliver (no frame in time, an unreadable frame, no display)."""


def rig_digest(rig: Rig) -> str:
    """sha256 of what a rig contributes to an image: geometry, cells and display model."""
    import dataclasses
    import hashlib
    import json

    data = {"camera_to_world": np.asarray(rig.camera_to_world).tolist(), "fov": rig.camera_fov,
            "lcd_to_world": np.asarray(rig.lcd_to_world).tolist(), "cells": list(rig.lcd_cells),
            "sample_size": rig.sample_size, "display": dataclasses.asdict(rig.display)}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=list).encode()).hexdigest()


@runtime_checkable
class Display(Protocol):
    cells: tuple[int, int]

    def show(self, pattern: np.ndarray) -> None:
        """Show (3, h, w) drive values in [0, 1] until the next call."""


@runtime_checkable
class Camera(Protocol):
    linear: bool
    rectified: bool

    def capture(self, exposure: float) -> np.ndarray:
        """One frame (H, W, 3) in [0, 1] taken with ``exposure`` seconds."""


def check_pattern(pattern: np.ndarray, cells: tuple[int, int]) -> np.ndarray:
    """``pattern`` as float32 (3, h, w) in [0, 1], or a clear error."""
    p = np.asarray(pattern, dtype=np.float32)
    if p.shape != (3, *cells):
        raise ValueError(f"a pattern for this LCD must be (3, {cells[0]}, {cells[1]}), got {p.shape}")
    if not np.isfinite(p).all() or p.min() < 0 or p.max() > 1:
        raise ValueError("pattern drive values must be finite and in [0, 1]")
    return p


class SimulatedRig:
    """A display and a camera simulated on a known material.

    Args:
        svbrdf: the material on the sample (one, no batch dimension needed).
        rig: the scene (geometry and display model).
        method, spp, seed: the renderer; every pattern is rendered with the same ``seed``, as a
            real rig shows every pattern to the same sensor.
        gain: relative exposure per unit radiance and second (X = gain * radiance * t).
        noise: sensor noise on the linear signal before the response (``bits`` is ignored: the
            response's code levels quantise).
        response: the camera's response; ``None`` is a linear RAW sensor (``levels`` codes).
        levels: code levels of a linear sensor (0: unquantised float frames).
        color_matrix: (3, 3) the sensor's RGB from radiance RGB (crosstalk of its colour filters).
    """

    rectified = True

    def __init__(self, svbrdf: SVBRDF, rig: Rig, *, method: str = "mitsuba", spp: int = 64, seed: int = 0,
                 gain: float = 1.0, noise: SensorNoise | None = None, response: Response | None = None,
                 levels: int = 0, color_matrix: np.ndarray | None = None):
        if gain <= 0 or not np.isfinite(gain):
            raise ValueError(f"gain must be positive, got {gain}")
        self.color_matrix = None if color_matrix is None else np.asarray(color_matrix, np.float64)
        self.place(svbrdf)
        if method == "mitsuba" and Rig.from_scene(rig.source).display != rig.display:
            raise ValueError("method='mitsuba' renders the scene file's display model, and this rig's was changed "
                             "in memory: write it into a scene file (capture.display.write_display_model) and read "
                             "the rig from there")
        self.rig, self.method, self.spp, self.seed = rig, method, spp, seed
        self.gain, self.noise, self.response, self.levels = gain, noise, response, levels
        self.cells = rig.lcd_cells
        self.linear = response is None
        self._pattern: np.ndarray | None = None
        self.frames_taken = 0

    def frame_settings(self) -> dict:
        """Everything besides the shown pattern and the exposure that decides this camera's frames
        (JSON data; a capture session stores it and refuses to resume when it changed)."""
        import dataclasses
        import hashlib

        def digest(*arrays) -> str:
            h = hashlib.sha256()
            for a in arrays:
                h.update(np.ascontiguousarray(np.asarray(a, np.float64)).tobytes())
            return h.hexdigest()

        r = self.rig
        return {"gain": self.gain, "method": self.method, "spp": self.spp, "seed": self.seed,
                "noise": None if self.noise is None else dataclasses.asdict(self.noise), "levels": self.levels,
                "response_sha256": None if self.response is None else digest(self.response.log_exposure),
                "color_matrix": None if self.color_matrix is None else self.color_matrix.tolist(),
                "material_sha256": digest(self.svbrdf.encoded().detach().cpu().numpy()),
                "rig_sha256": rig_digest(r)}

    def place(self, svbrdf: SVBRDF) -> None:
        """Put another material (a calibration target) on the sample."""
        if svbrdf.batch_size != 1:
            raise ValueError(f"a simulated rig holds one material, got a batch of {svbrdf.batch_size}")
        self.svbrdf, self._radiance = svbrdf, None

    def show(self, pattern: np.ndarray) -> None:
        p = check_pattern(pattern, self.cells)
        if self._pattern is None or not np.array_equal(p, self._pattern):
            self._pattern, self._radiance = p, None

    def radiance(self) -> np.ndarray:
        """(H, W, 3) linear radiance of the sample under the shown pattern (rendered once)."""
        if self._pattern is None:
            raise DeviceError("the simulated display shows nothing yet: call show() before capture()")
        if self._radiance is None:
            with torch.no_grad():
                img = render(self.svbrdf, torch.from_numpy(self._pattern)[None], self.rig, method=self.method,
                             spp=self.spp, seed=self.seed)
            self._radiance = img[0, 0].permute(1, 2, 0).numpy().astype(np.float64)
            if self.color_matrix is not None:
                self._radiance = np.einsum("ij,hwj->hwi", self.color_matrix, self._radiance)
        return self._radiance

    def capture(self, exposure: float) -> np.ndarray:
        if not exposure > 0 or not np.isfinite(exposure):
            raise ValueError(f"exposure must be a positive number of seconds, got {exposure}")
        x = self.gain * self.radiance() * exposure
        if self.noise is not None and (self.noise.shot > 0 or self.noise.read > 0):
            # a generator keyed by (seed, pattern, exposure): the same frame on every run
            key = zlib.crc32(self._pattern.tobytes() + np.float64(exposure).tobytes())
            g = torch.Generator().manual_seed(self.seed * 1_000_003 + key)
            n = SensorNoise(shot=self.noise.shot, read=self.noise.read, white=self.noise.white)
            x = n(torch.from_numpy(x), g).numpy()
        self.frames_taken += 1
        if self.response is not None:
            return self.response.pixel_value(x).astype(np.float32)
        z = np.clip(x, 0.0, 1.0)
        if self.levels:
            z = np.round(z * (self.levels - 1)) / (self.levels - 1)
        return z.astype(np.float32)


class FileDropCamera:
    """Frames written into ``folder`` by a tethering tool.

    ``capture`` notes the files present, calls ``trigger(exposure)`` if given (e.g.
    :func:`controller_trigger`), then waits up to ``timeout`` seconds for a new image file (PNG,
    JPEG or EXR) whose size has stopped changing, and reads it as (H, W, 3) in [0, 1].

    Args:
        folder: where frames appear.
        trigger: called with the exposure time before waiting (None: someone else triggers).
        timeout: seconds to wait for a frame.
        linear: frames are linear (RAW converted to linear, or EXR) rather than response-encoded.
        rectified: frames are already on the sample's texel grid.
    """

    def __init__(self, folder: str | Path, *, trigger: Callable[[float], None] | None = None,
                 timeout: float = 30.0, linear: bool = False, rectified: bool = False, poll: float = 0.05):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise DeviceError(f"{self.folder}: the camera's drop folder does not exist")
        self.trigger, self.timeout, self.poll = trigger, timeout, poll
        self.linear, self.rectified = linear, rectified

    def _frames(self) -> dict[Path, int]:
        return {p: p.stat().st_size for p in self.folder.iterdir()
                if p.suffix.lower() in imageio.READ_SUFFIXES and not p.name.startswith(".")}

    def capture(self, exposure: float) -> np.ndarray:
        before = set(self._frames())
        if self.trigger is not None:
            self.trigger(exposure)
        deadline = time.monotonic() + self.timeout
        sizes: dict[Path, int] = {}
        while time.monotonic() < deadline:
            new = {p: s for p, s in self._frames().items() if p not in before}
            stable = sorted(p for p, s in new.items() if s > 0 and sizes.get(p) == s)
            if stable:
                return self._read(stable[0])
            sizes = new
            time.sleep(self.poll)
        raise DeviceError(f"no new frame appeared in {self.folder} within {self.timeout:g} s "
                          f"(exposure {exposure:g} s); is the tethering tool writing there?")

    def _read(self, path: Path) -> np.ndarray:
        a = imageio.read_image(path).astype(np.float32)
        if a.ndim == 2:
            a = np.repeat(a[..., None], 3, -1)
        if a.ndim != 3 or a.shape[-1] < 3:
            raise DeviceError(f"{path}: a frame must be a grey or RGB image, got shape {a.shape}")
        return a[..., :3]


def controller_trigger(controller) -> Callable[[float], None]:
    """A trigger for :class:`FileDropCamera` from a controller: set the shutter, then fire."""

    def trigger(exposure: float) -> None:
        controller.shutter(exposure)
        controller.trigger()

    return trigger


class ImageFileDisplay:
    """Writes the shown pattern to ``path`` (PNG, one pixel per cell, 8-bit drive values) and
    calls ``on_show(path)`` if given, for a viewer or a display program to pick up."""

    def __init__(self, path: str | Path, cells: tuple[int, int] = (32, 32),
                 on_show: Callable[[Path], None] | None = None):
        self.path, self.cells, self.on_show = Path(path), tuple(cells), on_show

    def show(self, pattern: np.ndarray) -> None:
        p = check_pattern(pattern, self.cells)
        imageio.write_png(self.path, p.transpose(1, 2, 0))
        if self.on_show is not None:
            self.on_show(self.path)


class WindowDisplay:
    """Full-screen pattern window through matplotlib (nearest-neighbour cells, no axes).

    Needs a GUI backend (TkAgg, QtAgg, ...) and a screen: the LCD must be the window's screen.
    ``settle`` seconds are waited after drawing so that the panel has switched before a capture.
    """

    def __init__(self, cells: tuple[int, int] = (32, 32), settle: float = 0.1):
        import matplotlib

        if matplotlib.get_backend().lower() in ("agg", "pdf", "svg", "ps", "cairo", "template"):
            raise DeviceError(f"no GUI backend for a display window (matplotlib backend "
                              f"{matplotlib.get_backend()!r}); set MPLBACKEND=TkAgg on a machine with a screen, "
                              "or use ImageFileDisplay with your own viewer")
        import matplotlib.pyplot as plt

        self.cells, self.settle, self._plt = tuple(cells), settle, plt
        self.fig = plt.figure(facecolor="black")
        self.ax = self.fig.add_axes([0, 0, 1, 1])
        self.ax.set_axis_off()
        self.im = self.ax.imshow(np.zeros((*self.cells, 3)), interpolation="nearest", vmin=0, vmax=1)
        try:
            self.fig.canvas.manager.full_screen_toggle()
        except AttributeError:
            pass
        plt.show(block=False)

    def show(self, pattern: np.ndarray) -> None:
        self.im.set_data(check_pattern(pattern, self.cells).transpose(1, 2, 0))
        self.fig.canvas.draw_idle()
        self._plt.pause(self.settle)


class TriggeredCamera:
    """A camera fired through a controller: each capture sets the controller's shutter, triggers,
    then collects the frame from ``camera`` (e.g. a :class:`SimulatedRig` standing in for the
    sensor the controller fires). Controller errors propagate, so a session stops with every
    earlier frame on disk."""

    def __init__(self, camera: Camera, controller):
        self.camera, self.controller = camera, controller
        self.linear, self.rectified = camera.linear, camera.rectified

    def capture(self, exposure: float) -> np.ndarray:
        controller_trigger(self.controller)(exposure)
        return self.camera.capture(exposure)

    def frame_settings(self) -> dict:
        """The fired camera's frame settings (see :meth:`SimulatedRig.frame_settings`), if it has any."""
        inner = getattr(self.camera, "frame_settings", None)
        return inner() if inner is not None else {}
