"""A capture session at the bench: the adaptive acquisition with every frame on disk.

    show L_0 -> exposure bracket -> HDR merge -> I_0 -> predict L_1..L_4 -> show and capture each
    -> reconstruct

Layout of a session folder (all written as soon as they exist; files are written to a temporary
name and renamed, and ``session.json`` is rewritten atomically after each one, so a crash or a
pulled cable loses at most the frame in flight):

    session.json            manifest: settings, every recorded file, the stage reached
    patterns/L0.npy ...     (3, h, w) drive values of each shown pattern
    raw/L0_e0.exr ...       camera frames as delivered ((H, W, 3) float32, values in [0, 1])
    radiance/L0.exr ...     HDR-merged linear radiance on the sample's texel grid
    lpdf.npy                the importance distribution (1, h, w) the patterns were predicted from
    maps.png, maps.exr      the reconstruction (SVBRDF strip and layered EXR)
    patterns.png, images.png  previews

``run(resume=True)`` reads the manifest back, checks that the settings agree, and continues
from the first missing frame; the reconstruction is then the same as an uninterrupted session's.

The manifest's settings hold everything that decides the frames besides the patterns: the
exposures, the camera's response and colour matrix, a digest of the rig and of the networks and
their acquisition settings (:class:`~mitsvbrdf.acquisition.AcquisitionSettings`),
whatever the caller adds (the scene and networks files, the resolution) and, for cameras that
report them (``frame_settings()``, e.g. the simulated rig's gain, noise, seed and material), the
camera's own settings. Its ``files`` table holds the size and sha256 of every file the session
wrote. On resume every recorded file is checked against it: a raw frame that is missing or
changed is captured again (and that step's radiance merged again), a step whose pattern file is
not the pattern to show is captured again, and derived files (radiance, prediction) that do not
match are recomputed; ``recaptured`` lists what was redone.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from .. import imageio
from ..acquisition import Acquisition, AdaptiveAcquisition
from ..errors import MitsvbrdfError
from ..svbrdf import SVBRDF
from ..viewing import pattern_strip, tonemap
from .devices import Camera, Display, rig_digest
from .hdr import Response, merge_hdr

MANIFEST = "session.json"
VERSION = 2  # 2: the files table (size and sha256 of every file) and the camera's frame settings


class SessionError(MitsvbrdfError):
    """A session folder that cannot be started or resumed as asked."""


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _state_digest(module: torch.nn.Module) -> str:
    """sha256 of a module's parameters and buffers (names, shapes and values)."""
    h = hashlib.sha256()
    for name, t in sorted(module.state_dict().items()):
        h.update(name.encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def merge_frames(frames: np.ndarray, exposures: np.ndarray, response: Response | None, *,
                 low: float = 0.02, high: float = 0.98) -> tuple[np.ndarray, dict[str, int]]:
    """Linear radiance (H, W, 3) from a bracket of frames (K, H, W, 3) taken at ``exposures`` (K,) s.

    Linear sensors (``response`` None): sum of unsaturated values over the sum of their exposure
    times (the maximum-likelihood estimate under shot noise; one frame gives value / t). Otherwise
    :func:`.hdr.merge_hdr`. Samples with no usable frame take the shortest exposure's estimate
    where saturated (a lower bound) and the longest's where dark; their counts are returned.
    """
    f = np.asarray(frames, dtype=np.float64)
    t = np.asarray(exposures, dtype=np.float64)
    if response is None:
        ok = f < high
        with np.errstate(invalid="ignore", divide="ignore"):
            rad = (f * ok).sum(0) / (ok * t[:, None, None, None]).sum(0)
        saturated, dark = ~ok.any(0), np.zeros(f.shape[1:], bool)
        rad[saturated] = (f[t.argmin()] / t.min())[saturated]
    else:
        res = merge_hdr(f, t, response, low=low, high=high)
        rad, saturated, dark = res.radiance, res.saturated, res.dark
        rad[saturated] = (response.exposure(f[t.argmin()]) / t.min())[saturated]
        fill = np.isnan(rad)
        rad[fill] = (response.exposure(f[t.argmax()]) / t.max())[fill]
    return rad.astype(np.float32), {"saturated": int(saturated.sum()), "dark": int(dark.sum())}


@dataclass
class BracketCapture:
    """Shows a pattern and captures an HDR bracket: the device side of a session.

    Args:
        display, camera: the devices (:mod:`.devices`).
        exposures: exposure times of the bracket, seconds.
        response: the camera's response (ignored for linear cameras).
        rectify: maps a camera frame (H, W, 3) onto the sample's texel grid; needed when the
            camera's frames are not rectified (e.g. ``CameraModel.rectify`` with the sample size
            and resolution bound).
        color_matrix: (3, 3) camera RGB -> the renderers' linear RGB, applied after merging.
        raw_only: take raw brackets only (calibrating the response itself): no response is
            needed, and :meth:`radiance` refuses.
    """

    display: Display
    camera: Camera
    exposures: tuple[float, ...] = (1.0,)
    response: Response | None = None
    rectify: Callable[[np.ndarray], np.ndarray] | None = None
    color_matrix: np.ndarray | None = None
    raw_only: bool = False

    def __post_init__(self):
        self.exposures = tuple(float(t) for t in self.exposures)
        if not self.exposures or not all(np.isfinite(t) and t > 0 for t in self.exposures):
            raise SessionError(f"exposures must be positive seconds, got {self.exposures}")
        if self.raw_only:
            return
        if not self.camera.linear and self.response is None:
            raise SessionError("this camera's frames are not linear: give its response (mitsvbrdf calibrate "
                               "response), or --camera-linear for RAW/EXR frames")
        if not self.camera.rectified and self.rectify is None:
            raise SessionError("this camera's frames are camera views: give a rectification onto the sample's "
                               "texel grid")

    def frame(self, exposure: float) -> np.ndarray:
        """One raw frame (H, W, 3) float32 at ``exposure`` seconds of what is shown."""
        f = np.asarray(self.camera.capture(exposure), dtype=np.float32)
        if f.ndim != 3 or f.shape[-1] != 3:
            raise ValueError(f"the camera returned a frame of shape {f.shape}, expected (H, W, 3)")
        return f

    def bracket(self, pattern: np.ndarray) -> list[np.ndarray]:
        """Show ``pattern`` (3, h, w) and take the bracket's raw frames."""
        self.display.show(pattern)
        return [self.frame(t) for t in self.exposures]

    def radiance(self, frames: list[np.ndarray]) -> tuple[np.ndarray, dict[str, int]]:
        """(3, H, W) float32 linear radiance on the texel grid from the bracket's raw frames."""
        if self.raw_only:
            raise ValueError("this capture takes raw brackets only (raw_only=True): it has no radiance")
        rad, counts = merge_frames(np.stack(frames), np.array(self.exposures),
                                   None if self.camera.linear else self.response)
        if self.rectify is not None and not self.camera.rectified:
            rad = np.asarray(self.rectify(rad), dtype=np.float32)
        if self.color_matrix is not None:
            rad = np.einsum("ij,hwj->hwi", np.asarray(self.color_matrix, np.float32), rad)
        return np.ascontiguousarray(rad.transpose(2, 0, 1)), counts

    def __call__(self, patterns: torch.Tensor) -> torch.Tensor:
        """In-memory capture for :meth:`~mitsvbrdf.acquisition.AdaptiveAcquisition.acquire`: (1, P, 3, h, w) -> (1, P, 3, H, W)."""
        out = [torch.from_numpy(self.radiance(self.bracket(p.cpu().numpy()))[0]) for p in patterns[0]]
        return torch.stack(out)[None]


class CaptureSession:
    """The adaptive acquisition of one material at the bench, resumable (module docstring).

    Args:
        folder: the session folder (created).
        acquisition: an :class:`~mitsvbrdf.acquisition.AdaptiveAcquisition` (L_0, the networks,
            their settings, the rig).
        capture: the devices and the HDR settings (:class:`BracketCapture`).
        settings: anything else that must not change on resume (scene, networks file, ...),
            JSON-serialisable; stored in the manifest.
    """

    def __init__(self, folder: str | Path, acquisition: AdaptiveAcquisition, capture: BracketCapture,
                 settings: dict | None = None):
        self.folder, self.acquisition, self.capture = Path(folder), acquisition, capture
        cam = capture.camera
        linear = bool(cam.linear)
        response = None if linear or capture.response is None else _sha256(
            np.ascontiguousarray(capture.response.log_exposure, np.float64).tobytes())
        frame = getattr(cam, "frame_settings", None)
        settings = {"exposures": list(capture.exposures), "linear": linear, "lcd_cells": list(acquisition.rig.lcd_cells),
                    "response_sha256": response,
                    "color_matrix": None if capture.color_matrix is None else np.asarray(capture.color_matrix).tolist(),
                    "rig_sha256": rig_digest(acquisition.rig), "networks_sha256": _state_digest(acquisition),
                    # how the networks acquire (L_pdf source and quadrature, I^spec, training grid): same
                    # weights, other patterns; and how they meet a finer capture
                    "acquisition": acquisition.settings.record(), "transfer": acquisition.transfer,
                    **{f"camera.{k}": v for k, v in (frame() if frame is not None else {}).items()},
                    **(settings or {})}
        # as the manifest will read it back (tuples become lists), so that a comparison is exact
        self.settings = json.loads(json.dumps(settings))
        self.manifest: dict = {}
        self.recaptured: list[str] = []  # files redone on resume because they were missing or changed

    # ---- files ----------------------------------------------------------------------------------

    def _path(self, rel: str) -> Path:
        return self.folder / rel

    def _save(self, rel: str, write: Callable[[Path], None], record: bool = True) -> str:
        """Write through a temporary file renamed into place (never a half-written file), and
        record its size and sha256 in the manifest's files table."""
        path = self._path(rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(".tmp-" + path.name)
        write(tmp)
        if record:
            data = tmp.read_bytes()
            self.manifest.setdefault("files", {})[rel] = {"bytes": len(data), "sha256": _sha256(data)}
        os.replace(tmp, path)
        return rel

    def _commit(self) -> None:
        text = json.dumps(self.manifest, indent=2)
        self._save(MANIFEST, lambda p: p.write_text(text), record=False)

    def _intact(self, rel: str | None) -> bool:
        """Whether ``rel`` is on disk with the size and sha256 recorded when it was written."""
        if rel is None:
            return False
        rec, path = self.manifest.get("files", {}).get(rel), self._path(rel)
        if rec is None or not path.is_file() or path.stat().st_size != rec["bytes"]:
            return False
        return _sha256(path.read_bytes()) == rec["sha256"]

    def _redo(self, rel: str) -> None:
        self.recaptured.append(f"{rel} ({'changed' if self._path(rel).exists() else 'missing'})")

    def _open(self, resume: bool) -> None:
        path = self._path(MANIFEST)
        if path.exists() and not resume:
            raise SessionError(f"{self.folder} already holds a session: pass --resume to continue it, "
                               "or choose another folder")
        if not path.exists():
            if resume:
                raise SessionError(f"{self.folder}: nothing to resume (no {MANIFEST})")
            self.folder.mkdir(parents=True, exist_ok=True)
            self.manifest = {"version": VERSION, "settings": self.settings, "steps": {}, "files": {}, "done": False}
            self._commit()
            return
        try:
            self.manifest = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise SessionError(f"{path}: unreadable manifest ({e})") from e
        if self.manifest.get("version") != VERSION:
            raise SessionError(f"{path}: session format {self.manifest.get('version')!r}, this version reads {VERSION} "
                               "(format 1 has no checksums to verify its frames by: start a new session)")
        old = self.manifest.get("settings", {})
        diff = sorted(k for k in set(old) | set(self.settings) if old.get(k) != self.settings.get(k))
        if diff:
            raise SessionError(f"{path}: cannot resume with different settings: "
                               + "; ".join(f"{k}: {old.get(k)!r} then, {self.settings.get(k)!r} now" for k in diff))

    # ---- the acquisition --------------------------------------------------------------------------

    def _step(self, k: int, pattern: np.ndarray) -> np.ndarray:
        """Capture (or read back) pattern k's bracket and radiance; returns (3, H, W). Frames on
        disk are used only when they are the recorded files and were taken under ``pattern``."""
        name = f"L{k}"
        steps = self.manifest["steps"]
        step = steps.get(name)
        if step is not None and not self._shows(step, pattern):
            # taken under another pattern (or one whose file changed): these frames cannot serve
            self.recaptured.append(f"{name} (its frames were not taken under this pattern)")
            step = None
        if step is None:
            step = steps[name] = {"frames": {}}
            step["pattern"] = self._save(f"patterns/{name}.npy", lambda p: np.save(p, pattern))
            self._commit()
        frames, shown = [], False
        for e, t in enumerate(self.capture.exposures):
            rel = step["frames"].get(str(e))
            if self._intact(rel):
                frames.append(imageio.read_image(self._path(rel)).astype(np.float32))
                continue
            if rel is not None:
                self._redo(rel)
            if not shown:
                self.capture.display.show(pattern)
                shown = True
            f = self.capture.frame(t)
            step["frames"][str(e)] = self._save(f"raw/{name}_e{e}.exr", lambda p: imageio.write_exr(p, f))
            step.pop("radiance", None)  # merged from other frames
            self._commit()  # the frame is safe from here on
            frames.append(f)
        if self._intact(step.get("radiance")):
            # contiguous like a fresh merge: the networks' convolutions round differently on strided input
            rad = imageio.read_image(self._path(step["radiance"])).transpose(2, 0, 1)
            return np.ascontiguousarray(rad, dtype=np.float32)
        if "radiance" in step:
            self._redo(step["radiance"])
        rad, counts = self.capture.radiance(frames)
        step["radiance"] = self._save(f"radiance/{name}.exr", lambda p: imageio.write_exr(p, rad.transpose(1, 2, 0)))
        step.update(counts)
        self._commit()
        return rad

    def _shows(self, step: dict, pattern: np.ndarray) -> bool:
        """Whether the step's recorded pattern file is intact and holds ``pattern``."""
        rel = step.get("pattern")
        return self._intact(rel) and np.array_equal(np.load(self._path(rel), allow_pickle=False), pattern)

    def run(self, *, resume: bool = False, progress: bool = True):
        """Run (or continue) the session; returns the :class:`~mitsvbrdf.acquisition.Acquisition`."""
        self._open(resume)
        bar = tqdm(total=6, desc="capture", disable=not progress)
        pipe = self.acquisition
        l0 = pipe.l0.cpu().numpy()
        i0 = torch.from_numpy(self._step(0, l0))
        bar.update(1)
        pred = self.manifest.get("prediction")
        if pred is not None and not all(self._intact(rel) for rel in pred.values()):
            # predicted again from I_0; a step shown a pattern that now differs is captured again
            for rel in pred.values():
                if not self._intact(rel):
                    self._redo(rel)
            del self.manifest["prediction"]
        if "prediction" not in self.manifest:
            adaptive, lpdf, initial = pipe.predict_patterns(i0[None])
            self.manifest["prediction"] = {
                "patterns": self._save("patterns/adaptive.npy", lambda p: np.save(p, adaptive[0].numpy())),
                "lpdf": self._save("lpdf.npy", lambda p: np.save(p, lpdf[0].numpy())),
                "initial": self._save("initial.exr", lambda p: initial.save(p)),
            }
            self._commit()
        pred = self.manifest["prediction"]
        adaptive = np.load(self._path(pred["patterns"]))
        bar.update(1)
        images = [i0]
        for k in range(1, adaptive.shape[0] + 1):
            images.append(torch.from_numpy(self._step(k, adaptive[k - 1])))
            bar.update(1)
        images_t = torch.stack(images)
        patterns = pipe.all_patterns(torch.from_numpy(adaptive)[None])[0]
        svbrdf = pipe.reconstruct(images_t[None], patterns[None])
        self._save("maps.exr", lambda p: svbrdf.save(p))
        self._save("maps.png", lambda p: svbrdf.save(p))
        self._save("patterns.png", lambda p: imageio.write_png(p, pattern_strip(patterns)))
        self._save("images.png", lambda p: imageio.write_png(p, pattern_strip(tonemap(images_t))))
        self.manifest.update(done=True, maps="maps.exr")
        self._commit()
        bar.update(1)
        bar.close()
        initial = SVBRDF.load(self._path(pred["initial"]))
        return Acquisition(patterns, images_t, svbrdf[0], torch.from_numpy(np.load(self._path(pred["lpdf"]))), initial)
