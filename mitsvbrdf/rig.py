"""The capture rig: camera, LCD and sample geometry plus the LCD's display model, from a scene file.

Frames and units (docs/conventions.md): metres; the sample is the square ``|x|, |y| <= size/2`` on the
plane z = 0 with normal +z; texel (i, j) of an H x W map is the point
``x = (j + 1/2) / W * size - size/2``, ``y = size/2 - (i + 1/2) / H * size`` (row 0 at the top).
A window of the sample (:meth:`Rig.window`, for crops of a large material that keep their place in
the rig) is a smaller square centred at ``(cx, cy)``; its texels are then shifted by that centre.
The LCD is a rectangle with corners ``c0..c3`` (Mitsuba rectangle local (-1,-1), (1,-1), (1,1),
(-1,1)); pattern cell (0, 0) sits at corner 0, columns run c0 -> c1 (coordinate u in [0, 1]) and
rows c0 -> c3 (coordinate v in [0, 1]). Its normal points towards the sample, the side it emits
into. Patterns are drive values in [0, 1], shaped (P, 3, h, w) or (B, P, 3, h, w).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .errors import PatternError, SceneError
from .scene_xml import SceneNode, load_scene_xml

#: The default rig, shipped inside the package (``mitsvbrdf scene --out FILE`` copies it out).
DEFAULT_SCENE = Path(__file__).resolve().parent / "scenes" / "lcd_rig.xml"


@dataclass(frozen=True)
class DisplayModel:
    """Drive value -> emitted radiance of the LCD. Optional parts are None when not modelled.

    Attributes:
        intensity: radiance (W m^-2 sr^-1, relative) of a cell driven at 1.0, per RGB channel.
        gamma: response exponent, radiance ~ drive^gamma (None: linear).
        color_matrix: 3x3 matrix applied to the (responded) drive RGB (None: identity).
        decay_cos_power: angular emission decay cos(theta_emit)^k (None: Lambertian emitter).
        decay_gradient: (gx, gy), positional ramp ``max(0, 1 + gx (u - 1/2) + gy (v - 1/2))``.
    """

    intensity: tuple[float, float, float] = (1.0, 1.0, 1.0)
    gamma: float | None = None
    color_matrix: tuple[tuple[float, ...], ...] | None = None
    decay_cos_power: float | None = None
    decay_gradient: tuple[float, float] | None = None

    def __post_init__(self):
        # Checked here so that every way of making a display model (scene file, with_display,
        # calibration) meets the same contract; from_scene adds the file's path to the message.
        i = np.asarray(self.intensity, dtype=float)
        if i.shape != (3,) or not np.all(np.isfinite(i)) or np.any(i <= 0):
            raise SceneError(f"lcd intensity must be 3 finite numbers > 0 (radiance of a cell driven "
                             f"at 1.0 per RGB channel), got {_fmt(self.intensity)}")
        if self.gamma is not None and not (np.isfinite(self.gamma) and self.gamma > 0):
            raise SceneError(f"lcd gamma must be a finite number > 0, got {self.gamma}")
        if self.color_matrix is not None:
            m = np.asarray(self.color_matrix, dtype=float)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise SceneError(f"lcd color_matrix must be 3x3 finite numbers, got {_fmt(self.color_matrix)}")
        if self.decay_cos_power is not None and not (np.isfinite(self.decay_cos_power) and self.decay_cos_power >= 0):
            raise SceneError(f"lcd decay_cos_power must be a finite number >= 0, got {self.decay_cos_power}")
        if self.decay_gradient is not None:
            g = np.asarray(self.decay_gradient, dtype=float)
            if g.shape != (2,) or not np.all(np.isfinite(g)):
                raise SceneError("lcd decay_gradient must be 2 finite numbers (gx, gy), got "
                                 f"{_fmt(self.decay_gradient)}")

    @property
    def has_decay(self) -> bool:
        """Whether the scene models any emission decay (angular or positional)."""
        return self.decay_cos_power is not None or self.decay_gradient is not None

    def radiance(self, drive: Tensor) -> Tensor:
        """Emitted radiance before decay, for drive values with RGB along dim -3 (``(..., 3, h, w)``)."""
        x = drive
        if self.gamma is not None:
            # The tiny floor keeps d(x^gamma)/dx finite at black cells for gamma < 1.
            x = x.clamp_min(1e-12) ** self.gamma
        if self.color_matrix is not None:
            m = torch.tensor(self.color_matrix, dtype=x.dtype, device=x.device)
            x = torch.einsum("ij,...jhw->...ihw", m, x)
        scale = torch.tensor(self.intensity, dtype=x.dtype, device=x.device).view(3, 1, 1)
        return x * scale

    def decay(self, uv: Tensor, cos_emit: Tensor) -> Tensor | None:
        """Multiplicative emission factor at LCD coordinates ``uv`` (..., 2) for emission cosine
        ``cos_emit`` (...), or None when the scene models no decay (so callers skip the work)."""
        if not self.has_decay:
            return None
        f = torch.ones_like(cos_emit)
        if self.decay_cos_power is not None:
            f = f * cos_emit.clamp_min(0.0) ** self.decay_cos_power
        if self.decay_gradient is not None:
            gx, gy = self.decay_gradient
            f = f * (1.0 + gx * (uv[..., 0] - 0.5) + gy * (uv[..., 1] - 0.5)).clamp_min(0.0)
        return f


@dataclass(frozen=True)
class LcdGeometry:
    """Torch view of the LCD for renderers: corner 0, edge vectors, unit normal, cell grid."""

    origin: Tensor  # (3,) corner 0
    edge_u: Tensor  # (3,) corner 1 - corner 0 (along columns)
    edge_v: Tensor  # (3,) corner 3 - corner 0 (along rows)
    normal: Tensor  # (3,) unit, towards the sample
    cells: tuple[int, int]  # (h, w)

    @property
    def area(self) -> Tensor:
        return torch.linalg.vector_norm(torch.linalg.cross(self.edge_u, self.edge_v))

    def point(self, uv: Tensor) -> Tensor:
        """World positions (..., 3) of LCD coordinates uv (..., 2) in [0, 1]^2."""
        return self.origin + uv[..., :1] * self.edge_u + uv[..., 1:2] * self.edge_v

    def hit(self, x: Tensor, d: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Where rays x + t d (N, 3) meet the LCD's plane: (uv (N, 2), not clamped to the LCD;
        distance t (N,); front (N,), whether the ray runs towards the emitting side). Rays that
        do not get t = -(distance of x from the plane) and front = False."""
        denom = d @ self.normal
        front = denom < -1e-6
        t = ((self.origin - x) @ self.normal) / torch.where(front, denom, -torch.ones_like(denom))
        rel = x + t[:, None] * d - self.origin
        uv = torch.stack([rel @ self.edge_u / (self.edge_u @ self.edge_u),
                          rel @ self.edge_v / (self.edge_v @ self.edge_v)], -1)
        return uv, t, front


def _fmt(v: object) -> str:
    """A display-model value for a message: numbers as written, nested sequences flattened."""
    a = np.asarray(v, dtype=float).reshape(-1)
    return "(" + ", ".join(f"{x:g}" for x in a) + ")" if a.size != 1 else f"{a[0]:g}"


def _to_tuple3(v: object, name: str, path: Path) -> tuple[float, float, float]:
    a = _numbers(v, name, path)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3 or not np.all(np.isfinite(a)):
        raise SceneError(f"{path}: lcd parameter {name!r} needs 1 or 3 finite numbers")
    return tuple(float(x) for x in a)


def texel_grid(resolution: int | tuple[int, int]) -> tuple[int, int]:
    """(H, W) of the sample's texel grid from N (square) or (H, W); ValueError unless both are >= 1."""
    h, w = (resolution, resolution) if isinstance(resolution, (int, np.integer)) else tuple(resolution)
    if int(h) < 1 or int(w) < 1:
        raise ValueError(f"resolution must be positive, got {resolution}")
    return int(h), int(w)


def per_texel(rig: "Rig", resolution: int | tuple[int, int], compute, dim: int):
    """``compute(rig, resolution)``, a tensor (or tuple of tensors) of per-texel geometry with the
    texels row-major along ``dim``; for a window (:meth:`Rig.window_texels`) the window's rows of
    ``compute(parent, (grid, grid))``, so that a cache inside ``compute`` keyed on the rig keeps
    one parent entry instead of missing on every window of a training run. Exact: a window's texels
    are the parent's texels (same positions, view directions, LCD and display)."""
    win = rig.window_texels(resolution)
    if win is None:
        return compute(rig, texel_grid(resolution))
    parent, grid, idx = win
    full = compute(parent, (grid, grid))
    if isinstance(full, tuple):
        return tuple(t.index_select(dim, idx.to(t.device)) for t in full)
    return full.index_select(dim, idx.to(full.device))


def _same_rig(a: "Rig", b: "Rig") -> bool:
    """Whether two rigs have the same camera, LCD, sample square and display (not their source)."""
    same_square = np.allclose([a.sample_size, *a.sample_centre], [b.sample_size, *b.sample_centre], rtol=0, atol=1e-12)
    return (same_square and np.array_equal(a.camera_to_world, b.camera_to_world)
            and np.array_equal(a.lcd_to_world, b.lcd_to_world)
            and (a.camera_fov, a.film_size, a.lcd_cells, a.display) == (b.camera_fov, b.film_size, b.lcd_cells, b.display))


@dataclass(frozen=True, eq=False)
class Rig:
    """Camera + LCD + sample geometry and the display model of one capture setup.

    Build it with :meth:`from_scene`. Geometry is stored in float64 numpy; methods return torch
    float32 tensors on the requested device.
    """

    camera_to_world: np.ndarray  # (4, 4)
    camera_fov: float  # degrees, along the film's x axis
    film_size: tuple[int, int]  # (H, W) of real photos
    lcd_to_world: np.ndarray  # (4, 4), Mitsuba rectangle [-1, 1]^2
    lcd_cells: tuple[int, int]  # (h, w)
    sample_size: float  # metres, side of the square sample
    display: DisplayModel
    source: str = "<memory>"
    #: (x, y) metres of the sample square's centre: the origin for a scene file's sample, elsewhere
    #: for a window of it (:meth:`window`)
    sample_centre: tuple[float, float] = (0.0, 0.0)
    #: (parent, grid, top, left, size) of a rig made by :meth:`window`; see :meth:`window_texels`
    window_of: tuple | None = dataclasses.field(default=None, repr=False)

    # ---- construction -------------------------------------------------------------------------

    @classmethod
    def from_scene(cls, path: str | Path | None = None, **defaults: object) -> "Rig":
        """Read the rig from a Mitsuba scene file (default: :data:`DEFAULT_SCENE`).

        The file needs a ``perspective`` sensor, a ``rectangle`` with an ``lcd`` emitter and a
        ``rectangle`` with an ``svbrdf_ggx`` BSDF (the sample, centred at the origin in z = 0).
        ``defaults`` override the file's ``<default>`` values.
        """
        path = Path(path) if path is not None else DEFAULT_SCENE
        root = load_scene_xml(path, **defaults)
        sensor = next((c for c in root.children if c.tag == "sensor"), None)
        if sensor is None:
            raise SceneError(f"{path}: no <sensor> (the camera) in the scene")
        lcd = _find_shape(root, "emitter", "lcd")
        if lcd is None:
            raise SceneError(f"{path}: no shape with an <emitter type=\"lcd\"> (the LCD) in the scene")
        sample = _find_shape(root, "bsdf", "svbrdf_ggx")
        if sample is None:
            raise SceneError(f"{path}: no shape with a <bsdf type=\"svbrdf_ggx\"> (the sample) in the scene")
        for shape, what in ((lcd, "LCD"), (sample, "sample")):
            if shape.type != "rectangle":
                raise SceneError(f"{path}: the {what} must be a rectangle, not {shape.type!r}")

        em = lcd.child("emitter")
        cells = (_cell_count(em, "cells_y", path), _cell_count(em, "cells_x", path))
        display = _display_model(em, path)

        film = sensor.child("film")
        film_size = (256, 256)
        if film is not None:
            film_size = (int(film.props.get("height", 256)), int(film.props.get("width", 256)))
        size = _sample_size(sample.props.get("to_world", np.eye(4)), path)
        rig = cls(
            camera_to_world=np.asarray(sensor.props.get("to_world", np.eye(4))),
            camera_fov=float(sensor.props.get("fov", 45.0)),
            film_size=film_size,
            lcd_to_world=np.asarray(lcd.props.get("to_world", np.eye(4))),
            lcd_cells=cells,
            sample_size=size,
            display=display,
            source=str(path),
        )
        rig._check_geometry()
        return rig

    def with_display(self, **changes: object) -> "Rig":
        """A copy with display-model fields replaced (e.g. ``decay_cos_power=2.0``)."""
        return dataclasses.replace(self, display=dataclasses.replace(self.display, **changes))

    def window(self, grid: int, top: int, left: int, size: int) -> "Rig":
        """The rig of a ``size`` x ``size`` window of texels, at row ``top`` and column ``left`` of a
        ``grid`` x ``grid`` map of this rig's sample: the same camera, LCD and display, the sample
        shrunk to the window's square and centred on it. Rendered with it, the window's maps give
        the window's part of the whole map's images (each texel keeps its place, and so its light
        and view directions), which is what training on crops of a large material needs; every
        renderer and L_pdf take their texel positions from :meth:`surface_points`."""
        for name, value in (("grid", grid), ("top", top), ("left", left), ("size", size)):
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
                raise ValueError(f"window {name} must be an integer, got {value!r}")
        if size < 1 or grid < size or not (0 <= top <= grid - size and 0 <= left <= grid - size):
            raise ValueError(f"a {size} x {size} window at row {top}, column {left} does not fit a {grid} x {grid} "
                             "grid (needs 1 <= size <= grid and 0 <= top, left <= grid - size)")
        s = self.sample_size / grid  # one texel's side
        cx, cy = self.sample_centre
        parent, origin = self, (top, left)
        if self.window_of is not None and self.window_of[4] == grid:  # a window of a window, same texels
            parent, _, top0, left0, _ = self.window_of
            grid, origin = self.window_of[1], (top0 + top, left0 + left)
        return dataclasses.replace(self, sample_size=s * size,
                                   sample_centre=(cx - self.sample_size / 2 + (left + size / 2) * s,
                                                  cy + self.sample_size / 2 - (top + size / 2) * s),
                                   window_of=(parent, grid, *origin, size))

    def window_texels(self, resolution: int | tuple[int, int]) -> "tuple[Rig, int, Tensor] | None":
        """``(parent, grid, index)`` when this rig is a window of ``parent`` (:meth:`window`) and
        ``resolution`` is the window's own texel grid: per-texel geometry at ``resolution`` is then
        the texels ``index`` (row-major, (size * size,) int64) of the parent's at ``grid`` x ``grid``,
        so a cache of per-texel geometry slices the parent's instead of recomputing it for every
        window of a training run. None otherwise, also for a rig altered after :meth:`window`
        (e.g. :meth:`with_display`): it no longer shares the parent's geometry."""
        if self.window_of is None:
            return None
        parent, grid, top, left, size = self.window_of
        if texel_grid(resolution) != (size, size) or not _same_rig(self, dataclasses.replace(parent, window_of=None).window(
                grid, top, left, size)):
            return None
        rows = torch.arange(top, top + size).view(-1, 1) * grid
        return parent, grid, (rows + torch.arange(left, left + size).view(1, -1)).reshape(-1)

    def sample_to_world(self) -> np.ndarray:
        """(4, 4) the sample rectangle's Mitsuba transform: local [-1, 1]^2 onto the sample square."""
        m = np.diag([self.sample_size / 2, self.sample_size / 2, 1.0, 1.0])
        m[:2, 3] = self.sample_centre
        return m

    def _check_geometry(self) -> None:
        c = self.corners_np()
        if not np.all(np.isfinite(c)):
            raise SceneError(f"{self.source}: the LCD's corners are not finite (check its to_world transform)")
        eu, ev = np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[0])
        if eu <= 0 or ev <= 0 or np.linalg.norm(np.cross(c[1] - c[0], c[3] - c[0])) <= 1e-6 * eu * ev:
            raise SceneError(f"{self.source}: the LCD must have a positive size, got {eu:.4g} m x {ev:.4g} m "
                             "(check the <scale> of its to_world transform)")
        n = self.lcd_normal_np()
        centre = c.mean(axis=0)
        if np.dot(n, -centre) <= 0:
            raise SceneError(f"{self.source}: the LCD faces away from the sample (its normal must point at it)")
        if np.min(c[:, 2]) <= 0:
            raise SceneError(f"{self.source}: the LCD must lie entirely above the sample plane z = 0")
        if self.camera_position_np()[2] <= 0:
            raise SceneError(f"{self.source}: the camera must be above the sample plane z = 0")
        if not 0 < self.camera_fov < 180:
            raise SceneError(f"{self.source}: the camera's fov must be in (0, 180) degrees, got {self.camera_fov:g}")
        if min(self.film_size) < 1:
            raise SceneError(f"{self.source}: the film must be at least 1 x 1 px, got {self.film_size[1]} x "
                             f"{self.film_size[0]}")

    # ---- geometry (numpy, float64) ------------------------------------------------------------

    def corners_np(self) -> np.ndarray:
        local = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], dtype=float)
        return (self.lcd_to_world @ local.T).T[:, :3]

    def lcd_normal_np(self) -> np.ndarray:
        c = self.corners_np()
        n = np.cross(c[1] - c[0], c[3] - c[0])
        return n / np.linalg.norm(n)

    def camera_position_np(self) -> np.ndarray:
        return self.camera_to_world[:3, 3].copy()

    # ---- torch accessors ----------------------------------------------------------------------

    @property
    def camera_position(self) -> Tensor:
        """(3,) camera centre of projection, metres."""
        return torch.tensor(self.camera_position_np(), dtype=torch.float32)

    @property
    def lcd_corners(self) -> Tensor:
        """(4, 3) LCD corners c0..c3, metres."""
        return torch.tensor(self.corners_np(), dtype=torch.float32)

    @property
    def lcd_normal(self) -> Tensor:
        """(3,) unit normal of the LCD, pointing towards the sample."""
        return torch.tensor(self.lcd_normal_np(), dtype=torch.float32)

    def lcd_geometry(self, device: torch.device | str | None = None,
                     dtype: torch.dtype = torch.float32) -> LcdGeometry:
        """The LCD as tensors for renderers (see :class:`LcdGeometry`)."""
        c = torch.tensor(self.corners_np(), dtype=dtype, device=device)
        return LcdGeometry(origin=c[0], edge_u=c[1] - c[0], edge_v=c[3] - c[0],
                           normal=torch.tensor(self.lcd_normal_np(), dtype=dtype, device=device),
                           cells=self.lcd_cells)

    def lcd_cell_corners(self, device=None) -> Tensor:
        """(h, w, 4, 3) corners of every cell, in the same c0..c3 order as the LCD's."""
        h, w = self.lcd_cells
        g = self.lcd_geometry(device, torch.float64)
        v, u = torch.meshgrid(torch.arange(h + 1, dtype=torch.float64, device=device) / h,
                              torch.arange(w + 1, dtype=torch.float64, device=device) / w, indexing="ij")
        p = g.point(torch.stack([u, v], -1))  # (h+1, w+1, 3)
        out = torch.stack([p[:-1, :-1], p[:-1, 1:], p[1:, 1:], p[1:, :-1]], dim=2)
        return out.float()

    def lcd_cell_centres(self, device=None) -> Tensor:
        """(h, w, 3) centres of the LCD cells."""
        return self.lcd_cell_corners(device).mean(dim=2)

    def surface_points(self, resolution: int | tuple[int, int] = 256, device=None) -> Tensor:
        """(H, W, 3) texel-centre positions on the sample (z = 0), metres."""
        h, w = texel_grid(resolution)
        s = self.sample_size
        cx, cy = self.sample_centre
        x = cx + (torch.arange(w, dtype=torch.float64, device=device) + 0.5) / w * s - s / 2
        y = cy + s / 2 - (torch.arange(h, dtype=torch.float64, device=device) + 0.5) / h * s
        yy, xx = torch.meshgrid(y, x, indexing="ij")
        return torch.stack([xx, yy, torch.zeros_like(xx)], dim=-1).float()

    def view_directions(self, resolution: int | tuple[int, int] = 256, device=None) -> Tensor:
        """(H, W, 3) unit vectors from each texel centre towards the camera's centre of projection."""
        p = self.surface_points(resolution, device).double()
        d = torch.tensor(self.camera_position_np(), device=device) - p
        return (d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)).float()

    # ---- display model ------------------------------------------------------------------------

    def check_patterns(self, patterns: Tensor) -> None:
        """Raise PatternError unless ``patterns`` is (P, 3, h, w) or (B, P, 3, h, w) drive values
        in [0, 1] on this LCD's cell grid, without NaN."""
        if not isinstance(patterns, Tensor):
            raise PatternError(f"patterns must be a torch tensor, got {type(patterns).__name__}")
        h, w = self.lcd_cells
        if patterns.ndim not in (4, 5) or tuple(patterns.shape[-3:]) != (3, h, w):
            raise PatternError(
                f"patterns must be shaped (P, 3, {h}, {w}) or (B, P, 3, {h}, {w}) for this "
                f"{h}x{w}-cell LCD, got {tuple(patterns.shape)}")
        if patterns.shape[-4] == 0:
            raise PatternError(f"patterns {tuple(patterns.shape)} hold no pattern: P must be >= 1")
        d = patterns.detach()
        # Expanded (stride 0: one pattern set shared by the batch's materials), each value is held
        # once; checked through the broadcast view, the reductions took milliseconds at B = 4.
        d = d[tuple(0 if stride == 0 and size > 1 else slice(None) for stride, size in zip(d.stride(), d.shape))]
        bad = ~torch.isfinite(d)
        if bad.any():
            raise PatternError(f"patterns contain {int(bad.sum())} NaN/Inf drive values")
        lo, hi = float(d.min()), float(d.max())
        if lo < -1e-6 or hi > 1 + 1e-6:
            raise PatternError(f"pattern drive values must lie in [0, 1], got range [{lo:.4g}, {hi:.4g}]")

    def material_radiance(self, patterns: Tensor, batch: int, device=None,
                          dtype: torch.dtype = torch.float32) -> Tensor:
        """Per-material cell radiance (B, P, 3, h * w) for renderers: patterns (P, 3, h, w) are
        shared by all ``batch`` materials, (B, P, 3, h, w) give each its own."""
        self.check_patterns(patterns)
        rad = self.display.radiance(patterns.to(device, dtype))
        if rad.ndim == 4:
            rad = rad.unsqueeze(0).expand(batch, *rad.shape)
        elif rad.shape[0] != batch:
            raise PatternError(f"per-material patterns have batch {rad.shape[0]}, the SVBRDF has {batch}")
        return rad.reshape(batch, rad.shape[1], 3, -1)

    def display_radiance(self, patterns: Tensor) -> Tensor:
        """Drive values (..., 3, h, w) -> emitted radiance per cell before decay, same shape."""
        self.check_patterns(patterns)
        return self.display.radiance(patterns)


def _find_shape(root: SceneNode, child_tag: str, child_type: str) -> SceneNode | None:
    for node in root.children:
        if node.tag == "shape":
            c = node.child(child_tag)
            if c is not None and c.type == child_type:
                return node
    return None


def _cell_count(em: SceneNode, name: str, path: Path) -> int:
    v = em.props.get(name, 32)
    try:
        n = float(v)
    except (TypeError, ValueError):
        n = float("nan")
    if not (np.isfinite(n) and n == int(n) and n >= 1):
        raise SceneError(f"{path}: lcd {name} must be a whole number of cells >= 1, got {v!r}")
    return int(n)


def _numbers(v: object, name: str, path: Path) -> np.ndarray:
    try:
        if isinstance(v, str):
            return np.asarray([float(t) for t in v.replace(",", " ").split()])
        return np.atleast_1d(np.asarray(v, dtype=float)).reshape(-1)
    except (TypeError, ValueError):
        raise SceneError(f"{path}: lcd {name} must be numbers, got {v!r}") from None


def _display_model(em: SceneNode, path: Path) -> DisplayModel:
    p = em.props
    matrix = None
    if "color_matrix" in p:
        vals = _numbers(p["color_matrix"], "color_matrix", path)
        if vals.size != 9:
            raise SceneError(f"{path}: lcd color_matrix needs 9 numbers, got {vals.size}")
        matrix = tuple(tuple(float(x) for x in row) for row in vals.reshape(3, 3))
    gradient = None
    if "decay_gradient" in p:
        g = _numbers(p["decay_gradient"], "decay_gradient", path)
        if g.size not in (2, 3) or (g.size == 3 and g[2] != 0):
            raise SceneError(f"{path}: lcd decay_gradient needs (gx, gy) (a vector with z = 0), got {_fmt(g)}")
        gradient = (float(g[0]), float(g[1]))
    gamma = float(_numbers(p["gamma"], "gamma", path)[0]) if "gamma" in p else None
    k = float(_numbers(p["decay_cos_power"], "decay_cos_power", path)[0]) if "decay_cos_power" in p else None
    try:
        return DisplayModel(intensity=_to_tuple3(p.get("intensity", 1.0), "intensity", path),
                            gamma=gamma, color_matrix=matrix, decay_cos_power=k, decay_gradient=gradient)
    except SceneError as e:
        raise SceneError(f"{path}: {e}") from None


def _sample_size(m: np.ndarray, path: Path) -> float:
    corners = (m @ np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], float).T).T[:, :3]
    ex, ey = corners[1] - corners[0], corners[3] - corners[0]
    ok = (np.allclose(corners[:, 2], 0, atol=1e-9) and np.allclose(corners.mean(0), 0, atol=1e-9)
          and abs(ex[1]) < 1e-9 and abs(ey[0]) < 1e-9 and ex[0] > 0 and ey[1] > 0)
    if not ok:
        raise SceneError(f"{path}: the sample rectangle must be axis-aligned in z = 0, centred at the "
                         "origin, with local x -> world +x and y -> world +y (scale it only)")
    if not np.isclose(ex[0], ey[1], rtol=1e-9):
        raise SceneError(f"{path}: the sample must be square, got {ex[0]:.4g} x {ey[1]:.4g} m")
    return float(ex[0])
