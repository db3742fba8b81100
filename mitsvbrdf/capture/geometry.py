"""Geometric calibration of the LCD's pose from its reflections in a flat mirror sample.

Show single lit cells (or a few at a time) on the LCD with a mirror in place of the sample; in the
rectified capture each lit cell (i, j) appears at a point x_ij of the sample plane (z = 0, metres,
e.g. the centroid of the bright spot). By the mirror law, the ray from x_ij along the camera ray
reflected about the plane's normal passes through that cell's centre. With the camera centre
known (camera calibration) and the LCD's size and cell grid known (from the scene), the LCD's
pose (3 rotation + 3 translation parameters around the scene's nominal pose) is the least-squares
fit of those point-to-ray distances. :func:`write_lcd_pose` puts the result into a copy of the
scene file as the LCD shape's ``to_world`` matrix.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import SceneError
from ..rig import Rig
from ..scene_xml import edit_scene


def cell_local(cells: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Local LCD coordinates (N, 4) homogeneous of cell centres (rows i, columns j) (N, 2)."""
    h, w = grid
    i, j = cells[:, 0].astype(float), cells[:, 1].astype(float)
    return np.stack([-1 + (2 * j + 1) / w, -1 + (2 * i + 1) / h, np.zeros_like(i), np.ones_like(i)], -1)


def mirror_points(lcd_to_world: np.ndarray, camera: np.ndarray, cells: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Where a flat mirror at z = 0 shows each cell centre to the camera: (N, 3) points."""
    p = (lcd_to_world @ cell_local(cells, grid).T).T[:, :3]
    c_img = camera * np.array([1.0, 1.0, -1.0])  # the camera's mirror image
    s = -c_img[2] / (p[:, 2] - c_img[2])
    return c_img + s[:, None] * (p - c_img)


def _rotation(w: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(w)
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def _posed(nominal: np.ndarray, x: np.ndarray) -> np.ndarray:
    """nominal LCD-to-world with a rotation x[:3] (about the LCD centre) and translation x[3:]."""
    m = nominal.copy()
    m[:3, :3] = _rotation(x[:3]) @ nominal[:3, :3]
    m[:3, 3] = nominal[:3, 3] + x[3:]
    return m


def ray_offsets(lcd_to_world: np.ndarray, rig: Rig, cells: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) offsets of the cell centres (N, 2) of an LCD at ``lcd_to_world`` from the camera rays
    reflected at their mirror points (N, 3): zero for the true pose and exact points."""
    rays = points - rig.camera_position_np()
    rays[:, 2] *= -1  # reflected about the mirror's normal
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    p = (lcd_to_world @ cell_local(cells, rig.lcd_cells).T).T[:, :3] - points
    return p - (p * rays).sum(1, keepdims=True) * rays


def fit_lcd_pose(rig: Rig, cells: np.ndarray, points: np.ndarray) -> np.ndarray:
    """LCD-to-world matrix (4, 4) from lit cells (N, 2) (row, column) and their mirror points (N, 3)."""
    from scipy.optimize import least_squares

    cells, points = np.asarray(cells), np.asarray(points, float)
    if cells.shape[0] < 4 or points.shape != (cells.shape[0], 3):
        raise ValueError(f"need >= 4 lit cells with one (x, y, z) point each, got {cells.shape} and {points.shape}")
    def residuals(x: np.ndarray) -> np.ndarray:
        return ray_offsets(_posed(rig.lcd_to_world, x), rig, cells, points).ravel()

    res = least_squares(residuals, np.zeros(6), x_scale=np.array([0.01, 0.01, 0.01, 0.001, 0.001, 0.001]))
    return _posed(rig.lcd_to_world, res.x)


def write_lcd_pose(scene: str | Path, out: str | Path, lcd_to_world: np.ndarray) -> Path:
    """Copy ``scene`` to ``out`` with the LCD shape's to_world replaced by ``lcd_to_world``."""

    def edit(root: ET.Element) -> None:
        shapes = [s for s in root.iter("shape") if any(e.get("type") == "lcd" for e in s.iter("emitter"))]
        if len(shapes) != 1:
            raise SceneError(f"{scene}: expected one shape with an lcd emitter, found {len(shapes)}")
        tr = shapes[0].find("transform")
        if tr is None:
            tr = ET.SubElement(shapes[0], "transform", {"name": "to_world"})
        for op in list(tr):
            tr.remove(op)
        ET.SubElement(tr, "matrix", {"value": " ".join(f"{v:.12g}" for v in np.asarray(lcd_to_world).ravel())})

    return edit_scene(scene, out, edit)
