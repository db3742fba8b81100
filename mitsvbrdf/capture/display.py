"""Calibration of the LCD's display model, written back into a scene file.

* Drive -> radiance: show uniform grey levels on a diffuse target, average each (HDR, linear)
  capture; radiance ~ drive^gamma, so gamma is the slope of ln(mean) against ln(drive) (levels
  below 5% drive are left out: their signal is mostly noise).
* Emission decay: show a white pattern on a diffuse target; the capture's *shape* (divided by its
  mean, which removes the unknown albedo and intensity) is compared with renders of the same target
  under candidate cos^k decays, and k is the best fit (bounded 1-D minimisation).

:func:`write_display_model` copies a scene file with the ``lcd`` emitter's parameters replaced
(comments and everything else kept), so the renderers and the training use the calibration.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import torch

from ..errors import SceneError
from ..render import render
from ..rig import Rig
from ..svbrdf import SVBRDF
from ..scene_xml import edit_scene


def fit_gamma(drives: np.ndarray, means: np.ndarray, min_drive: float = 0.05) -> float:
    """Exponent of radiance ~ drive^gamma from grey levels (K,) and their mean captures (K,)."""
    d, m = np.asarray(drives, float), np.asarray(means, float)
    keep = (d >= min_drive) & (m > 0)
    if keep.sum() < 2:
        raise ValueError(f"need at least 2 grey levels above drive {min_drive} with signal, got {int(keep.sum())}")
    slope, _ = np.polyfit(np.log(d[keep]), np.log(m[keep]), 1)
    return float(slope)


def diffuse_target(rig: Rig, size: int, albedo: float = 0.8) -> SVBRDF:
    """A flat Lambertian calibration target filling the sample square."""
    return SVBRDF.constant(diffuse=albedo, specular=0.0, roughness=1.0, size=size)


def fit_decay_power(white_capture: np.ndarray, rig: Rig, bounds: tuple[float, float] = (0.0, 8.0)) -> float:
    """k of the cos^k emission decay from a capture (H, W, 3) of a diffuse target under a white
    pattern, using the renderer (diffuse lobe, reference quadrature) as the model."""
    from scipy.optimize import minimize_scalar

    h, w = white_capture.shape[:2]
    target = diffuse_target(rig, h)
    pattern = torch.ones(1, 3, *rig.lcd_cells)
    shape = np.asarray(white_capture, float).mean(-1)
    shape = shape / shape.mean()

    def error(k: float) -> float:
        model = rig.with_display(decay_cos_power=float(k))
        with torch.no_grad():
            img = render(target, pattern, model, lobes="diffuse")[0, 0].mean(0).numpy()
        return float(((img / img.mean() - shape) ** 2).mean())

    res = minimize_scalar(error, bounds=bounds, method="bounded", options={"xatol": 1e-3})
    return float(res.x)


def write_display_model(scene: str | Path, out: str | Path, **params) -> Path:
    """Copy ``scene`` to ``out`` with the lcd emitter's parameters set (e.g. gamma=2.2,
    decay_cos_power=1.5, intensity=(1.9, 2.0, 2.1), color_matrix="1 0 0 0 1 0 0 0 1"); returns ``out``."""

    def edit(root: ET.Element) -> None:
        emitters = [e for e in root.iter("emitter") if e.get("type") == "lcd"]
        if len(emitters) != 1:
            raise SceneError(f"{scene}: expected one lcd emitter, found {len(emitters)}")
        em = emitters[0]
        for name, value in params.items():
            for old in [c for c in em if c.get("name") == name]:
                em.remove(old)
            if isinstance(value, str):
                ET.SubElement(em, "string", {"name": name, "value": value})
            elif np.ndim(value) == 1:  # an RGB triple, e.g. the intensity per channel
                ET.SubElement(em, "rgb", {"name": name, "value": ", ".join(f"{v:.9g}" for v in value)})
            else:
                ET.SubElement(em, "float", {"name": name, "value": f"{value:.9g}"})

    return edit_scene(scene, out, edit)
