"""Calibration results written back into a Mitsuba scene file, and read from it (the copy-and-edit
machinery, :func:`mitsvbrdf.scene_xml.edit_scene`, lives with the scene-file reader).

Geometry and the display model go into the scene's own elements (the LCD shape's ``to_world``,
the ``lcd`` emitter's parameters, the sensor's ``fov`` and principal point), so the renderers and
the training use them. The camera's own calibration, which Mitsuba does not model, goes into
``<default>`` entries that Mitsuba ignores and the capture reads:

    camera_response       a .npy of the inverse response ln X per code (path relative to the scene)
    camera_color_matrix   9 numbers, row-major: camera RGB -> the renderers' linear RGB
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..checks import check_out_file
from ..errors import SceneError
from ..scene_xml import edit_scene
from .hdr import Response


def set_defaults(root: ET.Element, **values: str) -> None:
    """Set (or add, after the existing ones) ``<default name=... value=...>`` entries."""
    existing = {d.get("name"): d for d in root.findall("default")}
    for name, value in values.items():
        if name in existing:
            existing[name].set("value", value)
        else:
            at = len(root.findall("default"))
            root.insert(at, ET.Element("default", {"name": name, "value": value}))


def write_camera_calibration(scene: str | Path, out: str | Path, *, response: Response | None = None,
                             color_matrix: np.ndarray | None = None) -> Path:
    """Copy ``scene`` to ``out`` with the camera's response (saved beside ``out`` as
    ``<out stem>.camera_response.npy``) and/or colour matrix recorded."""
    out = check_out_file("out", out)  # before the response file is written beside it
    values = {}
    if color_matrix is not None:
        m = np.asarray(color_matrix, float)
        if m.shape != (3, 3) or not np.isfinite(m).all():
            raise ValueError(f"a colour matrix is 3x3 and finite, got {m.shape}")
        values["camera_color_matrix"] = " ".join(f"{v:.9g}" for v in m.ravel())
    npy = None
    if response is not None:
        npy = out.with_name(out.stem + ".camera_response.npy")
        out.parent.mkdir(parents=True, exist_ok=True)
        np.save(npy, response.log_exposure)
        values["camera_response"] = npy.name
    try:
        return edit_scene(scene, out, lambda root: set_defaults(root, **values))
    except BaseException:
        if npy is not None:  # no response file without the scene that names it
            npy.unlink(missing_ok=True)
        raise


def read_camera_calibration(scene: str | Path) -> tuple[Response | None, np.ndarray | None]:
    """The camera's response and colour matrix recorded in ``scene`` (None where absent)."""
    scene = Path(scene)
    try:
        root = ET.parse(scene).getroot()
    except (OSError, ET.ParseError) as e:
        raise SceneError(f"{scene}: cannot read the scene file ({e})") from e
    d = {e.get("name"): e.get("value") for e in root.findall("default")}
    response = matrix = None
    if d.get("camera_response"):
        path = scene.parent / d["camera_response"]
        try:
            response = Response(np.load(path, allow_pickle=False).astype(np.float64))
        except (OSError, ValueError) as e:
            raise SceneError(f"{scene}: camera_response {path} cannot be read ({e})") from e
    if d.get("camera_color_matrix"):
        try:
            matrix = np.array([float(v) for v in d["camera_color_matrix"].replace(",", " ").split()]).reshape(3, 3)
        except ValueError as e:
            raise SceneError(f"{scene}: camera_color_matrix must be 9 numbers, got {d['camera_color_matrix']!r}") from e
    return response, matrix
