"""Calibration procedures at the bench: what to show, what to capture, what to fit.

Each procedure drives a :class:`Bench` (the display, the camera with its HDR bracket, and a way
to put a target on the sample: a prompt at a real bench, a material swap in simulation) and returns
the fitted values; the ``mitsvbrdf calibrate`` command writes them into a scene file. Order:
camera response, then the display model, then colour, with the geometry (intrinsics, LCD pose)
any time. Targets:

* ``white``: a flat diffuse target of known albedo (e.g. Spectralon, or matte white paper);
* ``chart``: a ColorChecker filling the sample square, 4 rows x 6 columns, dark skin top left;
* ``mirror``: a flat front-surface mirror in place of the sample.

Units: exposures in seconds, drives in [0, 1], radiance relative (the display calibration sets the
LCD's ``intensity`` so that renders match the merged captures).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from ..errors import MitsvbrdfError
from ..render import render
from ..rig import Rig
from ..svbrdf import SVBRDF
from .devices import SimulatedRig
from .color import chart_reference_rgb, delta_e_2000, fit_color_matrix
from .display import diffuse_target, fit_decay_power, fit_gamma
from .geometry import fit_lcd_pose, ray_offsets
from .hdr import Response, calibrate_response
from .session import BracketCapture

CHART_LAYOUT = (4, 6)


class CalibrationError(MitsvbrdfError):
    """Captures that cannot determine what a calibration step fits (e.g. a too narrow bracket)."""


@dataclass
class Bench:
    """The devices for calibration: ``capture`` shows patterns and merges brackets;
    ``place(target)`` asks for (or, simulated, puts) a target on the sample."""

    capture: BracketCapture
    place: Callable[[str], None]

    def radiance(self, pattern: np.ndarray) -> np.ndarray:
        """(H, W, 3) merged linear radiance under ``pattern`` (3, h, w)."""
        return self.capture.radiance(self.capture.bracket(pattern))[0].transpose(1, 2, 0)

    def bracket(self, pattern: np.ndarray) -> np.ndarray:
        """Raw frames (K, H, W, 3) of the bracket under ``pattern``."""
        return np.stack(self.capture.bracket(pattern))


def calibration_targets(size: int, rig: Rig, albedo: float = 0.8) -> dict[str, SVBRDF]:
    """The calibration targets as materials on a size x size texel grid, for simulation."""
    return {"white": diffuse_target(rig, size, albedo), "chart": chart_material(size),
            "mirror": SVBRDF.constant(diffuse=0.0, specular=1.0, roughness=0.001, size=size)}


def simulated_bench(truth: Rig, size: int, exposures=(1.0,), **camera) -> tuple[Bench, "SimulatedRig"]:
    """A bench on the simulated rig (``camera``: :class:`SimulatedRig` options; the reference
    renderer unless ``method`` says otherwise) whose ``place`` swaps in the targets."""
    targets = calibration_targets(size, truth)
    sim = SimulatedRig(targets["white"], truth, **{"method": "reference", **camera})
    return Bench(BracketCapture(sim, sim, exposures, response=sim.response), lambda t: sim.place(targets[t])), sim


def uniform(cells: tuple[int, int], drive: float = 1.0) -> np.ndarray:
    return np.full((3, *cells), drive, np.float32)


def ramp(cells: tuple[int, int]) -> np.ndarray:
    """A drive ramp across the LCD's columns: a spread of radiances in one frame."""
    r = np.linspace(0.02, 1.0, cells[1], dtype=np.float32)
    return np.broadcast_to(r, (3, *cells)).copy()


# ---- camera response ------------------------------------------------------------------------------


def response_from_bracket(frames: np.ndarray, exposures: np.ndarray, *, points: int = 400,
                          levels: int = 256) -> Response:
    """Inverse response from raw frames (K, H, W, C) of one static scene: ``points`` samples
    (pixel, channel) at evenly spaced quantiles of their summed values over the bracket (monotonic
    in radiance), so that the whole radiance range, and with it the code range, is represented."""
    f = np.asarray(frames, float).reshape(len(frames), -1)
    if len(set(np.asarray(exposures, float).tolist())) < 2:
        raise CalibrationError(f"the camera response needs a bracket of at least 2 different exposure times, "
                               f"got {list(np.asarray(exposures, float))}")
    if f.min() > 0.1 or f.max() < 0.9:
        raise CalibrationError(f"the bracket's values span only {f.min():.3f}..{f.max():.3f}: the response is only "
                         "determined where codes were seen; extend the exposures until the shortest frame is "
                         "dark (below 0.1) and the longest bright (above 0.9)")
    order = np.argsort(f.sum(0), kind="stable")
    pick = order[np.linspace(0, len(order) - 1, min(points, len(order))).astype(int)]
    return calibrate_response(f[:, pick], np.asarray(exposures, float), levels=levels)


def calibrate_camera_response(bench: Bench, cells: tuple[int, int], *, levels: int = 256) -> Response:
    """Show a ramp on the white target and fit the response to the raw bracket."""
    bench.place("white")
    return response_from_bracket(bench.bracket(ramp(cells)), np.array(bench.capture.exposures), levels=levels)


# ---- display model ----------------------------------------------------------------------------------


def calibrate_display(bench: Bench, rig: Rig, *, albedo: float = 0.8, drives=(0.1, 0.25, 0.4, 0.55, 0.7, 0.85, 1.0),
                      fit_decay: bool = True) -> dict:
    """Gamma from uniform grey levels, the decay exponent from the white pattern's shape, then the
    LCD's per-channel intensity so that a render of the white target matches the capture.

    Returns ``{"gamma", "decay_cos_power", "intensity" (3,), "relative_rmse"}``; the last is the
    white capture against the calibrated render, relative to its mean."""
    bench.place("white")
    cells = rig.lcd_cells
    caps = [bench.radiance(uniform(cells, d)) for d in drives]
    gamma = fit_gamma(np.array(drives), np.array([c.mean() for c in caps]))
    white = caps[int(np.argmax(drives))] if max(drives) == 1.0 else bench.radiance(uniform(cells))
    decay = fit_decay_power(white, rig) if fit_decay else rig.display.decay_cos_power
    model = rig.with_display(gamma=gamma, decay_cos_power=decay, intensity=(1.0, 1.0, 1.0))
    size = white.shape[0]
    with torch.no_grad():
        pred = render(diffuse_target(rig, size, albedo), torch.from_numpy(uniform(cells))[None], model)[0, 0]
    pred = pred.permute(1, 2, 0).numpy()
    intensity = white.reshape(-1, 3).mean(0) / pred.reshape(-1, 3).mean(0)
    err = np.sqrt(((pred * intensity - white) ** 2).mean()) / white.mean()
    return {"gamma": float(gamma), "decay_cos_power": None if decay is None else float(decay),
            "intensity": [float(v) for v in intensity], "relative_rmse": float(err)}


# ---- colour ------------------------------------------------------------------------------------------


def chart_material(size: int, reference: np.ndarray | None = None) -> SVBRDF:
    """A Lambertian ColorChecker on the sample (4 x 6 patches, for simulation)."""
    ref = np.clip(chart_reference_rgb() if reference is None else reference, 0, 1).reshape(*CHART_LAYOUT, 3)
    rows = (np.arange(size) * CHART_LAYOUT[0]) // size
    cols = (np.arange(size) * CHART_LAYOUT[1]) // size
    diffuse = torch.from_numpy(ref[rows][:, cols].transpose(2, 0, 1)).float()[None]
    m = SVBRDF.constant(diffuse=0.5, specular=0.0, roughness=1.0, size=size)
    return SVBRDF(normal=m.normal, diffuse=diffuse, roughness=m.roughness, specular=m.specular)


def patch_means(image: np.ndarray, layout: tuple[int, int] = CHART_LAYOUT, inner: float = 0.5) -> np.ndarray:
    """(rows * cols, C) means over the central ``inner`` fraction of each patch of an (H, W, C) image."""
    h, w = image.shape[:2]
    out = []
    for i in range(layout[0]):
        for j in range(layout[1]):
            cy, cx = (i + 0.5) * h / layout[0], (j + 0.5) * w / layout[1]
            ry, rx = inner * h / layout[0] / 2, inner * w / layout[1] / 2
            out.append(image[int(cy - ry):int(np.ceil(cy + ry)), int(cx - rx):int(np.ceil(cx + rx))].reshape(-1, image.shape[2]).mean(0))
    return np.array(out)


def calibrate_color(bench: Bench, rig: Rig) -> dict:
    """Capture the chart under the white pattern; fit M (camera RGB -> rendered RGB) against a
    render of the reference chart through the (display-calibrated) rig. Returns ``{"matrix",
    "delta_e" (24,)}``, Delta E 2000 of the corrected patches' reflectance."""
    bench.place("chart")
    cap = bench.radiance(uniform(rig.lcd_cells))
    with torch.no_grad():
        ref = render(chart_material(cap.shape[0]), torch.from_numpy(uniform(rig.lcd_cells))[None], rig)[0, 0]
        grey = render(chart_material(cap.shape[0], np.ones((24, 3))), torch.from_numpy(uniform(rig.lcd_cells))[None], rig)[0, 0]
    ref_p = patch_means(ref.permute(1, 2, 0).numpy())
    grey_p = patch_means(grey.permute(1, 2, 0).numpy())  # irradiance at each patch
    measured = patch_means(cap)
    m = fit_color_matrix(measured, ref_p)
    corrected = measured @ m.T / grey_p
    return {"matrix": m, "delta_e": delta_e_2000(corrected, np.clip(chart_reference_rgb(), 0, 1))}


# ---- LCD pose from a mirror ---------------------------------------------------------------------------


def gray_code_patterns(cells: tuple[int, int]) -> list[tuple[str, int, np.ndarray]]:
    """Binary-reflected Gray code stripes over the LCD's columns then rows: (axis, bit, pattern)
    with pattern (3, h, w) lit where the bit of the cell's column (row) code is 1."""
    h, w = cells
    out = []
    for axis, n, index in (("col", w, np.arange(w)[None, :]), ("row", h, np.arange(h)[:, None])):
        gray = index ^ (index >> 1)
        for b in range(max(1, int(np.ceil(np.log2(n))))):
            lit = np.broadcast_to((gray >> b) & 1, (h, w)).astype(np.float32)
            out.append((axis, b, np.repeat(lit[None], 3, 0)))
    return out


def decode_gray(bits: np.ndarray) -> np.ndarray:
    """Cell indices from Gray-code bits (B, ...) (least significant first)."""
    g = sum(bits[b].astype(np.int64) << b for b in range(bits.shape[0]))
    n, shift = g.copy(), 1
    while (g >> shift).any():
        n ^= g >> shift
        shift += 1
    return n


def mirror_correspondences(bench: Bench, rig: Rig, *, contrast: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Show Gray codes and their inverses over the mirror and decode, for every texel that clearly
    sees a cell, which one. Each cell's reflection is then reduced to the centroid of its texels
    (a per-texel fit would carry the half-cell quantisation of a sharp mirror, and the LCD's tilt
    is only weakly observable: it needs points to ~0.1 mm). Cells whose reflection touches the
    frame's border or is small (cut by the sample's edge) are dropped: their centroids are biased.
    Returns cells (N, 2) (row, column) and sample-plane points (N, 3)."""
    bits: dict[str, list[np.ndarray]] = {"col": [], "row": []}
    valid = None
    for axis, _, pattern in gray_code_patterns(rig.lcd_cells):
        on, off = bench.radiance(pattern).mean(-1), bench.radiance(1.0 - pattern).mean(-1)
        clear = np.abs(on - off) > contrast * np.maximum(on, off)
        valid = clear if valid is None else valid & clear
        bits[axis].append(on > off)
    bright = bench.radiance(uniform(rig.lcd_cells)).mean(-1)
    valid &= bright > contrast * bright.max()
    col, row = decode_gray(np.stack(bits["col"])), decode_gray(np.stack(bits["row"]))
    valid &= (col < rig.lcd_cells[1]) & (row < rig.lcd_cells[0])
    h, w = rig.lcd_cells
    label = np.where(valid, row * w + col, -1)
    points = rig.surface_points(valid.shape).numpy().astype(np.float64)
    count = np.bincount(label[valid], minlength=h * w)
    centroid = np.stack([np.bincount(label[valid], weights=points[..., k][valid], minlength=h * w)
                         for k in range(3)], -1) / np.maximum(count, 1)[:, None]
    edge = np.zeros(valid.shape, bool)
    edge[[0, -1], :] = edge[:, [0, -1]] = True
    cut = np.bincount(label[valid & edge], minlength=h * w) > 0
    keep = (count > 0.5 * np.median(count[count > 0])) & ~cut if count.any() else count > 0
    ids = np.flatnonzero(keep)
    return np.stack([ids // w, ids % w], -1), centroid[ids]


def calibrate_lcd_pose(bench: Bench, rig: Rig) -> dict:
    """The LCD's pose from Gray-coded mirror correspondences (see :mod:`.geometry`): each texel's
    reflected camera ray passes through the cell it sees. Returns ``{"lcd_to_world" (4, 4),
    "cells": N, "rms_mm"}``, the rms distance of the cell centres from their rays."""
    bench.place("mirror")
    cells, points = mirror_correspondences(bench, rig)
    if len(cells) < 20:
        raise ValueError(f"only {len(cells)} LCD cells are clearly seen in the mirror: is the mirror in place?")
    pose = fit_lcd_pose(rig, cells, points)
    d = ray_offsets(pose, rig, cells, points)
    return {"lcd_to_world": pose, "cells": int(len(cells)),
            "rms_mm": float(1e3 * np.sqrt((d ** 2).sum(1).mean()))}
