"""Read the parts of a Mitsuba 3 XML scene file that the torch side of mitsvbrdf needs, and write
edited copies of one (:func:`edit_scene`; :func:`write_integrator_options` for estimator variants).

The rig's scene files (the default one is ``mitsvbrdf/scenes/lcd_rig.xml``) are real Mitsuba
scenes (Mitsuba loads them once the project's plugins are registered). The torch renderers, the
rig geometry and the display model read the same file here without Mitsuba: ``<default>``
substitution, typed properties (``float``, ``integer``, ``boolean``, ``string``, ``rgb``,
``point``/``vector``) and ``to_world`` transforms built from ``translate``, ``scale``, ``rotate``,
``matrix`` and ``lookat`` exactly as Mitsuba composes them (each element is applied after the
previous ones: M = op @ M).
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import SceneError

_NUM = re.compile(r"[,\s]+")


@dataclass
class SceneNode:
    """One plugin element: its tag (shape, emitter, ...), ``type``, ``id``, properties, children."""

    tag: str
    type: str
    id: str | None
    props: dict[str, object] = field(default_factory=dict)
    children: list["SceneNode"] = field(default_factory=list)

    def child(self, tag: str) -> "SceneNode | None":
        """The first child element with this tag, or None."""
        return next((c for c in self.children if c.tag == tag), None)


def _floats(text: str, where: str, count: int | None = None) -> list[float]:
    """The numbers in ``text``; all must be finite (no number in a scene means NaN or Inf), and
    exactly ``count`` of them when given."""
    try:
        vals = [float(t) for t in _NUM.split(text.strip()) if t]
    except ValueError as e:
        raise SceneError(f"{where}: cannot read numbers from {text!r}") from e
    if not all(math.isfinite(v) for v in vals):
        raise SceneError(f"{where}: numbers must be finite, got {text!r}")
    if count is not None and len(vals) != count:
        raise SceneError(f"{where}: expected {count} number{'s' if count > 1 else ''}, got {text!r}")
    return vals


def lookat_matrix(origin: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Mitsuba's look-at: local +z towards the target, local +x = normalize(up x dir)."""
    d = target - origin
    if np.linalg.norm(d) == 0:
        raise SceneError("lookat: origin and target coincide")
    d = d / np.linalg.norm(d)
    left = np.cross(up, d)
    if np.linalg.norm(left) < 1e-12:
        raise SceneError("lookat: 'up' is parallel to the viewing direction")
    left = left / np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    x, y, z = axis
    r = np.array(
        [
            [c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
            [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
            [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = r
    return m


def _vec_attr(el: ET.Element, default: float, where: str) -> np.ndarray:
    """A 3-vector from ``value="x, y, z"`` (or a scalar) or from x/y/z attributes."""
    if "value" in el.attrib:
        v = _floats(el.attrib["value"], where)
        if len(v) == 1:
            return np.array(v * 3)
        if len(v) == 3:
            return np.array(v)
        raise SceneError(f"{where}: expected 1 or 3 numbers, got {len(v)}")
    return np.array([_floats(el.attrib.get(k, str(default)), f"{where} {k}", 1)[0] for k in "xyz"])


def _transform(el: ET.Element, where: str) -> np.ndarray:
    m = np.eye(4)
    for op in el:
        w = f"{where} <{op.tag}>"
        if op.tag == "translate":
            t = np.eye(4)
            t[:3, 3] = _vec_attr(op, 0.0, w)
            m = t @ m
        elif op.tag == "scale":
            m = np.diag([*_vec_attr(op, 1.0, w), 1.0]) @ m
        elif op.tag == "rotate":
            axis = _vec_attr(op, 0.0, w)
            if np.linalg.norm(axis) == 0:
                raise SceneError(f"{w}: rotation axis is zero")
            m = _rotation(axis, _floats(op.attrib.get("angle", "0"), f"{w} angle", 1)[0]) @ m
        elif op.tag == "matrix":
            v = _floats(op.attrib.get("value", ""), w)
            if len(v) == 9:
                t = np.eye(4)
                t[:3, :3] = np.array(v).reshape(3, 3)
            elif len(v) == 16:
                t = np.array(v).reshape(4, 4)
            else:
                raise SceneError(f"{w}: expected 9 or 16 numbers, got {len(v)}")
            m = t @ m
        elif op.tag == "lookat":
            vecs = [np.array(_floats(op.attrib.get(k, d), w)) for k, d in
                    (("origin", ""), ("target", ""), ("up", "0 1 0"))]
            if any(len(v) != 3 for v in vecs):
                raise SceneError(f"{w}: origin, target and up need 3 numbers each")
            m = lookat_matrix(*vecs) @ m
        else:
            raise SceneError(f"{w}: unsupported transform operation")
    return m


def _parse_node(el: ET.Element, defaults: dict[str, str], path: Path) -> SceneNode:
    node = SceneNode(tag=el.tag, type=el.attrib.get("type", ""), id=el.attrib.get("id"))
    for sub in el:
        attrs = {k: _subst(v, defaults, path) for k, v in sub.attrib.items()}
        sub.attrib.clear()
        sub.attrib.update(attrs)
        name = attrs.get("name")
        where = f"{path}: <{sub.tag} name={name!r}>"
        if sub.tag == "transform":
            node.props[name or "to_world"] = _transform(sub, where)
        elif sub.tag in ("float",):
            node.props[name] = _floats(attrs.get("value", ""), where, 1)[0]
        elif sub.tag == "integer":
            text = _value(attrs, where)
            try:
                node.props[name] = int(text)
            except ValueError as e:
                raise SceneError(f"{where}: not an integer: {text!r}") from e
        elif sub.tag == "boolean":
            node.props[name] = _value(attrs, where).strip().lower() in ("true", "1", "yes")
        elif sub.tag == "string":
            node.props[name] = _value(attrs, where)
        elif sub.tag in ("rgb", "point", "vector", "spectrum"):
            node.props[name] = _vec_attr(sub, 0.0, where)
        elif sub.tag in ("default", "ref"):
            continue
        else:
            node.children.append(_parse_node(sub, defaults, path))
    return node


def _value(attrs: dict[str, str], where: str) -> str:
    if "value" not in attrs:
        raise SceneError(f"{where}: no value attribute")
    return attrs["value"]


def _subst(value: str, defaults: dict[str, str], path: Path) -> str:
    def repl(m: re.Match) -> str:
        key = m.group(1)
        if key not in defaults:
            raise SceneError(f"{path}: ${key} is used but no <default name={key!r}> is given")
        return defaults[key]

    return re.sub(r"\$(\w+)", repl, value)


def load_scene_xml(path: str | Path, **overrides: object) -> SceneNode:
    """Parse a scene file into a :class:`SceneNode` tree; ``overrides`` replace ``<default>`` values."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: scene file not found")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise SceneError(f"{path}: not a valid XML scene file ({e})") from e
    if root.tag != "scene":
        raise SceneError(f"{path}: the root element is <{root.tag}>, expected <scene>")
    defaults = {}
    for d in root.iter("default"):
        if "name" not in d.attrib or "value" not in d.attrib:
            raise SceneError(f"{path}: a <default> needs name and value attributes, got {d.attrib}")
        defaults[d.attrib["name"]] = d.attrib["value"]
    defaults.update({k: str(v) for k, v in overrides.items()})
    return _parse_node(root, defaults, path)


def edit_scene(scene: str | Path, out: str | Path, edit: Callable[[ET.Element], None]) -> Path:
    """Copy ``scene`` to ``out`` after ``edit(root)`` changed its element tree; comments (also
    those before the root element, which ElementTree drops) are kept. Returns ``out``."""
    scene, out = Path(scene), Path(out)
    try:
        text = scene.read_text()
        tree = ET.ElementTree(ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))))
    except (OSError, ET.ParseError) as e:
        raise SceneError(f"{scene}: cannot read the scene file ({e})") from e
    edit(tree.getroot())
    ET.indent(tree, space="    ")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text[:text.find("<scene")] + ET.tostring(tree.getroot(), encoding="unicode") + "\n")
    return out


#: The Python types an integrator option may have, and their scene-file tags.
INTEGRATOR_OPTION_TAGS = {str: "string", bool: "boolean", int: "integer", float: "float"}


def write_integrator_options(scene: str | Path, out: str | Path, **options: str | bool | int | float) -> Path:
    """Copy ``scene`` to ``out`` with these parameters on its integrator (``sampler="independent"``,
    ``cv_blocks=16``, ...; see plugins/importance_integrator.py), replacing any of the same name."""
    tags = INTEGRATOR_OPTION_TAGS

    def edit(root: ET.Element) -> None:
        integ = root.find("integrator")
        if integ is None:
            raise SceneError(f"{scene}: the scene has no <integrator>")
        for name, value in options.items():
            if type(value) not in tags:
                raise ValueError(f"integrator option {name}={value!r}: a string, boolean, integer or float")
            for old in [e for e in integ if e.get("name") == name]:
                integ.remove(old)
            text = str(value).lower() if type(value) is bool else str(value)  # Mitsuba reads "true"/"false"
            integ.append(ET.Element(tags[type(value)], {"name": name, "value": text}))

    return edit_scene(scene, out, edit)
