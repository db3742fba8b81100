"""Camera intrinsics calibration (checkerboard, Zhang's method) and rectification of camera frames
onto the sample's texel grid.

Frames and conventions:

- World: metres, the sample square ``|x|, |y| <= size/2`` on z = 0 (docs/conventions.md).
- Camera: Mitsuba's ``camera_to_world`` (as :attr:`mitsvbrdf.rig.Rig.camera_to_world`): the camera
  looks along its local +z; local +x is image *left* and local +y image *up* (Mitsuba's look-at
  puts local x = up x dir). A point with local coordinates (X, Y, Z) lands on pixel
  ``x = cx - fx X / Z``, ``y = cy - fy Y / Z``. This was measured with Mitsuba's
  ``sensor.sample_ray`` and is pinned by ``tests/test_capture_camera.py``.
- Pixels: ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; pixel (0, 0) covers
  [0, 1]^2, so its centre is (0.5, 0.5); x along columns, y along rows (down). Film position
  (u, v) in [0, 1]^2 of Mitsuba is pixel (u W, v H).
- Mitsuba's perspective sensor has square pixels, ``fx = fy = (W / 2) / tan(fov_x / 2)``, and its
  ``principal_point_offset_x/y`` are fractions of the film width/height with
  ``cx = W (1/2 - offset_x)``, ``cy = H (1/2 - offset_y)`` (note the minus sign: a positive offset
  moves the principal point left/up).
- Texels: an Hs x Ws map; texel coordinate (col + 0.5, row + 0.5) is the texel centre, which is the
  world point ``x = c / Ws * s - s/2``, ``y = s/2 - r / Hs * s`` (row 0 at y = +s/2), as
  :meth:`mitsvbrdf.rig.Rig.surface_points`.
- Checkerboard: ``squares = (rows, cols)``; the board's local frame has its z = 0 plane on the board
  and its origin at the board centre; square (a, b) (a along local y, b along local x, counted
  from the (-x, -y) corner) is black when a + b is even. Its inner corners
  (``inner = (rows - 1, cols - 1)``) are ordered row-major: corner (i, j) is at
  ``((j + 1) s - cols s / 2, (i + 1) s - rows s / 2, 0)``.

No lens distortion is modelled anywhere in this module (pinhole only): calibrate a lens whose
distortion matters after undistorting its frames, or extend the model.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np

from ..errors import SceneError
from ..rig import Rig, texel_grid
from ..scene_xml import edit_scene, load_scene_xml

# Mitsuba local camera frame (x left, y up, z forward) -> the usual vision frame (x right, y down).
_FLIP = np.diag([-1.0, -1.0, 1.0])


def _texel_to_plane(sample_size: float, resolution: tuple[int, int]) -> np.ndarray:
    """(3, 3) texel coordinate (col + 0.5, row + 0.5, 1) -> sample-plane point (x, y, 1), metres."""
    h, w = resolution
    s = float(sample_size)
    return np.array([[s / w, 0.0, -s / 2], [0.0, -s / h, s / 2], [0.0, 0.0, 1.0]])


def _apply_h(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a (3, 3) homography to (N, 2) points -> (N, 2)."""
    p = np.c_[pts, np.ones(len(pts))] @ h.T
    return p[:, :2] / p[:, 2:3]


# Pixel convention (centre at +0.5) <-> skimage's (centre at integer indices).
_TO_SK = np.array([[1.0, 0, -0.5], [0, 1.0, -0.5], [0, 0, 1.0]])
_FROM_SK = np.array([[1.0, 0, 0.5], [0, 1.0, 0.5], [0, 0, 1.0]])


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A pinhole camera (no lens distortion) in the world of a capture rig.

    Attributes:
        K: (3, 3) intrinsics in pixels, ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixel centres at
            integer + 0.5, y down.
        camera_to_world: (4, 4) Mitsuba-convention pose (local +z forward, +x image-left, +y
            image-up), as :attr:`mitsvbrdf.rig.Rig.camera_to_world`.
        size: (H, W) of the camera frames, pixels.
    """

    K: np.ndarray
    camera_to_world: np.ndarray
    size: tuple[int, int]

    # ---- construction -------------------------------------------------------------------------

    @classmethod
    def from_rig(cls, rig: Rig) -> "CameraModel":
        """The camera of ``rig``: ``fx = fy`` from its fov, film size from its film.

        ``Rig`` keeps neither ``fov_axis`` nor the principal point, so they are read from the
        rig's scene file (``rig.source``) when it exists: ``fov_axis`` x (default), y, smaller,
        larger or diagonal, and ``principal_point_offset_x/y``. A rig built in memory gets a
        centred principal point and an x-axis fov.
        """
        h, w = rig.film_size
        axis, ox, oy = "x", 0.0, 0.0
        if Path(rig.source).is_file():
            sensor = next((c for c in load_scene_xml(rig.source).children if c.tag == "sensor"), None)
            if sensor is not None:
                axis = str(sensor.props.get("fov_axis", "x")).lower()
                ox = float(sensor.props.get("principal_point_offset_x", 0.0))
                oy = float(sensor.props.get("principal_point_offset_y", 0.0))
        f = _focal_from_fov(rig.camera_fov, axis, (h, w))
        k = np.array([[f, 0.0, w * (0.5 - ox)], [0.0, f, h * (0.5 - oy)], [0.0, 0.0, 1.0]])
        return cls(K=k, camera_to_world=np.asarray(rig.camera_to_world, float), size=(int(h), int(w)))

    # ---- projection ---------------------------------------------------------------------------

    def projection_matrix(self) -> np.ndarray:
        """(3, 4) matrix from homogeneous world points (metres) to homogeneous pixels."""
        world_to_cam = np.linalg.inv(np.asarray(self.camera_to_world, float))
        return np.asarray(self.K, float) @ _FLIP @ world_to_cam[:3, :]

    @property
    def position(self) -> np.ndarray:
        """(3,) centre of projection in world metres."""
        return np.asarray(self.camera_to_world, float)[:3, 3].copy()

    def project(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3), metres -> pixel positions (N, 2) as (x, y).

        Points behind the camera get NaN (they are not imaged).
        """
        pts = np.asarray(points, float).reshape(-1, 3)
        p = np.c_[pts, np.ones(len(pts))] @ self.projection_matrix().T
        out = p[:, :2] / p[:, 2:3]
        out[p[:, 2] <= 0] = np.nan
        return out

    def plane_homography(self, plane_to_world: np.ndarray | None = None) -> np.ndarray:
        """(3, 3) homography from a plane's local (x, y, 1) (metres, the plane's local z = 0) to
        homogeneous pixels; default plane: the sample plane z = 0 of the world."""
        m = np.eye(4) if plane_to_world is None else np.asarray(plane_to_world, float)
        return self.projection_matrix() @ m[:, [0, 1, 3]]

    def sample_homography(self, sample_size: float, resolution: int | tuple[int, int]) -> np.ndarray:
        """(3, 3) homography from texel coordinates (col + 0.5, row + 0.5) of an Hs x Ws grid
        over the sample (side ``sample_size`` metres, on z = 0) to pixel (x, y)."""
        h = self.plane_homography() @ _texel_to_plane(sample_size, texel_grid(resolution))
        return h / abs(h[2, 2])  # abs: keep the sign of depth (see _in_front)

    # ---- resampling ---------------------------------------------------------------------------

    def rectify(self, frame: np.ndarray, sample_size: float, resolution: int | tuple[int, int]) -> np.ndarray:
        """Resample a camera frame (H, W) or (H, W, C) onto the sample's texel grid (Hs, Ws[, C]).

        Bilinear interpolation at each texel centre (``skimage.transform.warp`` with a
        ``ProjectiveTransform``); no prefilter, so a texel grid much coarser than the camera's
        footprint aliases (rectify at about the camera's resolution and downsample if needed).

        Raises:
            ValueError: the frame does not match the camera's size, or some texel's footprint (its
                square, projected) leaves the frame; the message says how many texels and by how
                many pixels at most.
        """
        from skimage.transform import ProjectiveTransform, warp

        frame = np.asarray(frame)
        if frame.shape[:2] != tuple(self.size):
            raise ValueError(f"frame is {frame.shape[:2]} pixels, the camera's film is {tuple(self.size)} (H, W)")
        hs, ws = texel_grid(resolution)
        hom = self.sample_homography(sample_size, (hs, ws))
        self._check_inside(hom, (hs, ws))
        # warp wants output (col, row) -> input (col, row), both with integer pixel centres.
        tf = ProjectiveTransform(matrix=_TO_SK @ hom @ _FROM_SK)
        out = warp(frame.astype(np.float64), tf, output_shape=(hs, ws, *frame.shape[2:]), order=1,
                   mode="edge", preserve_range=True)
        return out.astype(frame.dtype if np.issubdtype(frame.dtype, np.floating) else np.float64)

    def _check_inside(self, hom: np.ndarray, res: tuple[int, int]) -> None:
        hs, ws = res
        # Footprint of texel (r, c): the projected square with corners (c..c+1, r..r+1); the
        # projection of a square is convex, so its corners decide.
        cc, rr = np.meshgrid(np.arange(ws + 1.0), np.arange(hs + 1.0))
        p = np.c_[cc.ravel(), rr.ravel(), np.ones(cc.size)] @ hom.T
        behind = p[:, 2] <= 0
        xy = p[:, :2] / np.where(behind, 1.0, p[:, 2])[:, None]
        h, w = self.size
        over = np.maximum.reduce([-xy[:, 0], xy[:, 0] - w, -xy[:, 1], xy[:, 1] - h, np.zeros(len(xy))])
        over[behind] = np.inf
        bad_corner = (over > 1e-9).reshape(hs + 1, ws + 1)
        bad = bad_corner[:-1, :-1] | bad_corner[1:, :-1] | bad_corner[:-1, 1:] | bad_corner[1:, 1:]
        if bad.any():
            far = "behind the camera" if behind.any() else f"up to {over.max():.3g} px outside"
            raise ValueError(
                f"{int(bad.sum())} of {hs * ws} texels ({100 * bad.mean():.1f}%) have footprints leaving the "
                f"{h}x{w} camera frame ({far}); the sample is not fully in view")

    def view(self, texels: np.ndarray, sample_size: float) -> np.ndarray:
        """What the camera sees of a texel-grid image (Hs, Ws) or (Hs, Ws, C) lying on the sample:
        a frame (H, W[, C]), bilinear, 0 at pixels whose centre misses the sample (or whose ray
        points away from the plane). For simulating camera frames; no antialiasing."""
        from skimage.transform import ProjectiveTransform, warp

        texels = np.asarray(texels, float)
        hs, ws = texels.shape[:2]
        hom = self.sample_homography(sample_size, (hs, ws))
        inv = np.linalg.inv(hom)
        tf = ProjectiveTransform(matrix=_TO_SK @ inv @ _FROM_SK)
        h, w = self.size
        out = warp(texels, tf, output_shape=(h, w, *texels.shape[2:]), order=1, mode="edge", preserve_range=True)
        # Mask by where each pixel's ray meets the plane (sign of w: in front of the camera).
        xx, yy = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        q = np.stack([xx, yy, np.ones_like(xx)], -1) @ inv.T
        ok = _in_front(q)
        t = q[..., :2] / np.where(q[..., 2:3] == 0, 1e-300, q[..., 2:3])
        ok &= (t[..., 0] >= 0) & (t[..., 0] <= ws) & (t[..., 1] >= 0) & (t[..., 1] <= hs)
        out[~ok] = 0.0
        return out


def _in_front(q: np.ndarray) -> np.ndarray:
    """Whether homogeneous plane points q (..., 3) = H^-1 (x, y, 1) are in front of the camera.

    Our homographies keep the depth's sign (H (t, 1) = depth (x, y, 1), never rescaled by a
    negative number), so q = (t, 1) / depth and q's last component has the sign of the depth.
    """
    return q[..., 2] > 0


def _focal_from_fov(fov_deg: float, axis: str, size: tuple[int, int]) -> float:
    """Focal length in pixels of Mitsuba's perspective sensor for its ``fov``/``fov_axis``."""
    h, w = size
    t = math.tan(math.radians(fov_deg) / 2)
    if axis == "smaller":
        axis = "x" if w <= h else "y"
    elif axis == "larger":
        axis = "x" if w >= h else "y"
    if axis == "x":
        return w / 2 / t
    if axis == "y":
        return h / 2 / t
    if axis == "diagonal":
        return math.hypot(w, h) / 2 / t
    raise SceneError(f"unsupported fov_axis {axis!r} (x, y, smaller, larger, diagonal)")


# ---- synthetic checkerboards --------------------------------------------------------------------


def checkerboard_points(inner: tuple[int, int], square: float) -> np.ndarray:
    """(N, 3) board-local positions (metres, z = 0) of the inner corners of a board with
    ``inner = (rows - 1, cols - 1)`` inner corners and square side ``square``, row-major."""
    m, n = int(inner[0]), int(inner[1])
    if m < 1 or n < 1:
        raise ValueError(f"inner corner counts must be positive, got {inner}")
    i, j = np.meshgrid(np.arange(m), np.arange(n), indexing="ij")
    x = (j.ravel() + 1) * square - (n + 1) * square / 2
    y = (i.ravel() + 1) * square - (m + 1) * square / 2
    return np.stack([x, y, np.zeros_like(x)], -1).astype(float)


def checkerboard_image(camera: CameraModel, board_to_world: np.ndarray, squares: tuple[int, int], square: float,
                       *, supersample: int = 4) -> np.ndarray:
    """A synthetic (H, W) float image in [0, 1] of a planar checkerboard seen by ``camera``.

    ``squares = (rows, cols)``; ``board_to_world`` (4, 4) places the board's local z = 0 plane
    (origin at its centre, see the module docstring for colours). Black squares are 0, white
    squares and the background 1; each pixel averages ``supersample**2`` point samples.
    """
    rows, cols = int(squares[0]), int(squares[1])
    ss = int(supersample)
    h, w = camera.size
    inv = np.linalg.inv(camera.plane_homography(board_to_world))
    off = (np.arange(ss) + 0.5) / ss
    xs = (np.arange(w)[:, None] + off[None, :]).ravel()
    ys = (np.arange(h)[:, None] + off[None, :]).ravel()
    xx, yy = np.meshgrid(xs, ys)
    q = np.stack([xx, yy, np.ones_like(xx)], -1) @ inv.T
    # Rays that meet the board's plane behind the camera see the background.
    front = _in_front(q)
    bx = q[..., 0] / q[..., 2] / square + cols / 2
    by = q[..., 1] / q[..., 2] / square + rows / 2
    on = front & (bx >= 0) & (bx < cols) & (by >= 0) & (by < rows)
    a, b = np.floor(np.where(on, by, 0)).astype(int), np.floor(np.where(on, bx, 0)).astype(int)
    img = np.where(on & ((a + b) % 2 == 0), 0.0, 1.0)
    return img.reshape(h, ss, w, ss).mean(axis=(1, 3))


# ---- corner detection ---------------------------------------------------------------------------


def _refine_symmetric(img: np.ndarray, pts: np.ndarray, radius: float, blur: float = 1.0) -> np.ndarray:
    """Sub-pixel X-corners (points (N, 2) as array (row, col), same shape out).

    Near an X-corner every checker edge is a straight line through the corner (perspective keeps
    lines straight), so the image is point-symmetric about it: I(q + d) = I(q - d), also after a
    symmetric blur. Each q minimises sum_d (I(q + d) - I(q - d))^2 over a disc of ``radius`` px,
    with cubic-spline interpolation of the image blurred by ``blur`` px (which damps pixel-level
    aliasing). Measured on synthetic boards: ~0.05 px worst case at 8x8 supersampling. (The
    gradient-orthogonality refinement tried first was 2-3x less accurate on such images.)
    """
    from scipy.ndimage import gaussian_filter, map_coordinates, spline_filter
    from scipy.optimize import least_squares

    coef = spline_filter(gaussian_filter(img, blur) if blur > 0 else img, order=3)
    r = int(radius)
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1].astype(float)
    # Half the disc: d and -d give the same residual.
    keep = (dy ** 2 + dx ** 2 <= radius ** 2) & ((dy > 0) | ((dy == 0) & (dx > 0)))
    dy, dx = dy[keep], dx[keep]
    out = np.asarray(pts, float).copy()
    for k in range(len(out)):
        def res(q: np.ndarray) -> np.ndarray:
            a = map_coordinates(coef, [q[0] + dy, q[1] + dx], order=3, prefilter=False, mode="nearest")
            b = map_coordinates(coef, [q[0] - dy, q[1] - dx], order=3, prefilter=False, mode="nearest")
            return a - b

        q = least_squares(res, out[k], method="lm").x
        if np.linalg.norm(q - out[k]) < radius:  # a wild jump means no corner here: keep the peak
            out[k] = q
    return out


def _symmetry(img: np.ndarray, pts: np.ndarray, r: int) -> np.ndarray:
    """Per point: how well a (2r+1)^2 patch matches its 180-degree rotation relative to its
    contrast (1 = perfect point symmetry, as at an X-corner; L-corners and edges score lower)."""
    h, w = img.shape
    score = np.zeros(len(pts))
    for k, (i, j) in enumerate(np.round(pts).astype(int)):
        if i - r < 0 or j - r < 0 or i + r >= h or j + r >= w:
            continue
        p = img[i - r:i + r + 1, j - r:j + r + 1]
        var = p.var()
        if var < 1e-6:
            continue
        score[k] = 1.0 - np.mean((p - p[::-1, ::-1]) ** 2) / (4 * var)
    return score


def _homography_dlt(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(3, 3) homography with dst ~ H src from (N >= 4, 2) correspondences: DLT with Hartley
    normalisation (centroid at 0, mean distance sqrt 2), so it is well conditioned in pixels."""
    def norm(p: np.ndarray) -> np.ndarray:
        c = p.mean(0)
        d = np.sqrt(((p - c) ** 2).sum(1)).mean()
        s = math.sqrt(2) / d if d > 0 else 1.0
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])

    ts, td = norm(src), norm(dst)
    a = _apply_h(ts, src)
    b = _apply_h(td, dst)
    z = np.zeros((len(a), 3))
    ah = np.c_[a, np.ones(len(a))]
    rows = np.r_[np.c_[ah, z, -b[:, :1] * ah], np.c_[z, ah, -b[:, 1:2] * ah]]
    h = np.linalg.svd(rows)[2][-1].reshape(3, 3)
    h = np.linalg.inv(td) @ h @ ts
    return h / h[2, 2]


def find_checkerboard_corners(image: np.ndarray, inner: tuple[int, int]) -> np.ndarray:
    """Inner corners of a checkerboard in an (H, W) (or (H, W, C), averaged) image.

    Returns (N, 2) pixel (x, y), N = inner[0] * inner[1], sub-pixel, ordered like
    :func:`checkerboard_points` (row-major over ``inner = (rows - 1, cols - 1)``), assuming the
    camera sees the board's front (+z) side and the square at the board's (-x, -y) corner is black.
    A board with rows + cols even (and every square board) looks the same rotated by 180 degrees;
    then the ordering whose board +x axis points most along the image's +x is returned.

    Detection: Harris response (``skimage.feature.corner_harris``) and its peaks
    (``corner_peaks``); candidates that are not point-symmetric (L-corners at the board's outer
    edge) are dropped; positions are refined to the centre of point symmetry
    (:func:`_refine_symmetric`; ``skimage.feature.corner_subpix`` is not used: it is not
    accurate to 0.1 px on X-corners); the grid order comes from the homography that maps the
    4 extreme corners of the point set onto the grid's corners, checked against all points and
    against the square colours.

    Raises:
        ValueError: if not exactly N corners are found, or they do not form the grid.
    """
    from scipy.spatial import ConvexHull, cKDTree
    from skimage.feature import corner_harris, corner_peaks

    img = np.asarray(image, float)
    if img.ndim == 3:
        img = img.mean(axis=2)
    m, n = int(inner[0]), int(inner[1])
    need = m * n
    if m < 2 or n < 2:
        raise ValueError(f"need at least 2 x 2 inner corners, got {inner}")
    lo, hi = np.percentile(img, 1), np.percentile(img, 99)
    img = (img - lo) / max(hi - lo, 1e-12)
    resp = corner_harris(img, sigma=1.5)
    cand = corner_peaks(resp, min_distance=3, threshold_rel=0.05, exclude_border=3).astype(float)
    if len(cand) < need:
        raise ValueError(f"found {len(cand)} corner candidates, expected {need} inner corners ({m} x {n}); "
                         "is the whole board in view, sharp and with enough contrast?")
    # Window size from the spacing of candidates: half the typical nearest-neighbour distance.
    d, _ = cKDTree(cand).query(cand, k=2)
    spacing = float(np.median(d[:, 1]))
    r = max(2, int(spacing * 0.4))
    sym = _symmetry(img, cand, r)
    cand = cand[sym > 0.55]  # X-corners score ~0.7-1 even off-centre by half a pixel, L-corners ~0.3
    if len(cand) != need:
        raise ValueError(f"found {len(cand)} checkerboard (X-)corners, expected {need} ({m} x {n} inner corners); "
                         "is the whole board in view, and are the inner-corner counts right?")
    pts = _refine_symmetric(img, cand, radius=float(np.clip(spacing * 0.35, 2.5, 8.0)))
    xy = pts[:, ::-1] + 0.5  # (row, col) indices -> pixel (x, y) with centres at +0.5

    # Order: map the grid's 4 corners onto the 4 hull points spanning the largest quadrilateral.
    hull = xy[ConvexHull(xy).vertices]
    if len(hull) > 40:  # keep the combinatorial search small (every k-th hull vertex)
        hull = hull[:: int(math.ceil(len(hull) / 40))]
    best, quad = -1.0, None
    for c in combinations(range(len(hull)), 4):
        q = hull[list(c)]
        area = 0.5 * abs(np.dot(q[:, 0], np.roll(q[:, 1], -1)) - np.dot(q[:, 1], np.roll(q[:, 0], -1)))
        if area > best:
            best, quad = area, q
    grid = np.array([[0, 0], [n - 1, 0], [n - 1, m - 1], [0, m - 1]], float)  # (j, i) corners, cyclic
    gj, gi = np.meshgrid(np.arange(n, dtype=float), np.arange(m, dtype=float))
    all_grid = np.c_[gj.ravel(), gi.ravel()]
    tree = cKDTree(xy)
    options = []
    for flip in (False, True):
        qq = quad[::-1] if flip else quad
        for shift in range(4):
            h = _homography_dlt(grid, np.roll(qq, shift, axis=0))
            pred = _apply_h(h, all_grid)
            dist, idx = tree.query(pred)
            if dist.max() > 0.25 * spacing or len(set(idx)) != need:
                continue
            h = _homography_dlt(all_grid, xy[idx])
            # Handedness: the camera sees the board's front, so board +x -> image right-ish and
            # board +y -> image up-ish, i.e. the Jacobian of grid -> pixel has a negative determinant.
            c0 = np.array([(n - 1) / 2, (m - 1) / 2])
            jac = np.stack([_apply_h(h, (c0 + e)[None])[0] - _apply_h(h, c0[None])[0] for e in np.eye(2)], 1)
            if np.linalg.det(jac) >= 0:
                continue
            # Colour: square (a, b) is black when a + b is even; in grid units (j, i) of the inner
            # corners its centre is (b - 1/2, a - 1/2). The right order has white minus black > 0.
            sa, sb = np.meshgrid(np.arange(m + 1), np.arange(n + 1), indexing="ij")
            centres = _apply_h(h, np.c_[sb.ravel() - 0.5, sa.ravel() - 0.5])
            val = _sample(img, centres)
            black = ((sa + sb) % 2 == 0).ravel()
            ok = np.isfinite(val)
            contrast = 0.0
            if (ok & black).any() and (ok & ~black).any():
                contrast = np.mean(val[ok & ~black]) - np.mean(val[ok & black])
            options.append((round(contrast, 2), float(jac[0, 0]), xy[idx]))
    if not options:
        raise ValueError(f"the {need} corners found do not form a {m} x {n} grid seen from the board's front")
    options.sort(key=lambda o: (o[0], o[1]), reverse=True)
    return options[0][2].copy()


def _sample(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Nearest-pixel values at pixel positions (N, 2); NaN outside the image."""
    h, w = img.shape
    j, i = np.floor(xy[:, 0]).astype(int), np.floor(xy[:, 1]).astype(int)
    ok = (i >= 0) & (i < h) & (j >= 0) & (j < w)
    out = np.full(len(xy), np.nan)
    out[ok] = img[i[ok], j[ok]]
    return out


# ---- Zhang's calibration ------------------------------------------------------------------------


def _v(h: np.ndarray, i: int, j: int) -> np.ndarray:
    a, b = h[:, i], h[:, j]
    return np.array([a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[1] * b[1],
                     a[2] * b[0] + a[0] * b[2], a[2] * b[1] + a[1] * b[2], a[2] * b[2]])


def _pose_from_homography(k: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) of a plane (object frame -> vision camera frame)."""
    a = np.linalg.inv(k) @ h
    lam = 1.0 / np.linalg.norm(a[:, 0])
    if a[2, 2] * lam < 0:  # the board must be in front of the camera
        lam = -lam
    r1, r2, t = lam * a[:, 0], lam * a[:, 1], lam * a[:, 2]
    u, _, vt = np.linalg.svd(np.c_[r1, r2, np.cross(r1, r2)])
    r = u @ vt  # nearest rotation to the noisy estimate
    if np.linalg.det(r) < 0:
        r = u @ np.diag([1, 1, -1]) @ vt
    return r, t


def calibrate_intrinsics(image_points: list[np.ndarray], object_points: np.ndarray,
                         size: tuple[int, int]) -> tuple[np.ndarray, float]:
    """Intrinsics K (3, 3) from views of a planar target, by Zhang's method.

    Args:
        image_points: per view, (N, 2) pixel (x, y) of the target's points (same order as
            ``object_points``), pixel centres at +0.5.
        object_points: (N, 3) target-local positions (metres, z = 0), e.g. from
            :func:`checkerboard_points`.
        size: (H, W) of the images; used for conditioning and the initial guess only.

    Returns:
        (K, rms): K with zero skew (fx, fy, cx, cy free) and the root-mean-square reprojection
        error in pixels (sqrt of the mean over points of dx^2 + dy^2).

    Method: a homography per view (normalised DLT), the closed-form B = K^-T K^-1 from
    v12 b = 0, (v11 - v22) b = 0 of all views, then Levenberg-Marquardt refinement of
    (fx, fy, cx, cy) and every view's pose on the reprojection error. No lens distortion.
    Views should differ in tilt (fronto-parallel or mutually parallel boards are degenerate).

    Raises:
        ValueError: fewer than 3 views, mismatched point counts, or a degenerate set of views.
    """
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    obj = np.asarray(object_points, float)
    if len(image_points) < 3:
        raise ValueError(f"Zhang's calibration needs at least 3 views of the target, got {len(image_points)}")
    if obj.ndim != 2 or obj.shape[1] != 3 or len(obj) < 4 or not np.allclose(obj[:, 2], 0):
        raise ValueError(f"object_points must be (N >= 4, 3) points on the target's z = 0 plane, got {obj.shape}")
    views = [np.asarray(p, float) for p in image_points]
    for k, p in enumerate(views):
        if p.shape != (len(obj), 2):
            raise ValueError(f"view {k}: image points are {p.shape}, expected ({len(obj)}, 2)")
    hgt, wid = size
    # Condition the closed form: pixels -> roughly [-1, 1].
    s = 2.0 / max(hgt, wid)
    nrm = np.array([[s, 0, -s * wid / 2], [0, s, -s * hgt / 2], [0, 0, 1.0]])
    homs = [_homography_dlt(obj[:, :2], p) for p in views]
    vs = []
    for h in homs:
        hn = nrm @ h
        vs += [_v(hn, 0, 1), _v(hn, 0, 0) - _v(hn, 1, 1)]
    b = np.linalg.svd(np.array(vs))[2][-1]
    bm = np.array([[b[0], b[1], b[3]], [b[1], b[2], b[4]], [b[3], b[4], b[5]]])
    if np.linalg.eigvalsh(bm)[0] < 0:  # b is defined up to sign
        bm = -bm
    try:
        l = np.linalg.cholesky(bm)  # B = L L^T, K^-1 = L^T up to scale
    except np.linalg.LinAlgError as e:
        raise ValueError("degenerate views: the closed-form intrinsics are not positive definite "
                         "(tilt the target differently between views)") from e
    kn = np.linalg.inv(l.T)
    kn /= kn[2, 2]
    k0 = np.linalg.inv(nrm) @ kn
    k0 = np.array([[k0[0, 0], 0, k0[0, 2]], [0, k0[1, 1], k0[1, 2]], [0, 0, 1.0]])  # zero skew
    if k0[0, 0] <= 0 or k0[1, 1] <= 0:
        raise ValueError("degenerate views: negative focal length in the closed-form solution")

    x0 = [k0[0, 0], k0[1, 1], k0[0, 2], k0[1, 2]]
    for h in homs:
        r, t = _pose_from_homography(k0, h)
        x0 += [*Rotation.from_matrix(r).as_rotvec(), *t]
    x0 = np.array(x0)
    obs = np.concatenate(views)

    def residuals(x: np.ndarray) -> np.ndarray:
        fx, fy, cx, cy = x[:4]
        out = []
        for v in range(len(views)):
            rv, t = x[4 + 6 * v:7 + 6 * v], x[7 + 6 * v:10 + 6 * v]
            pc = obj @ Rotation.from_rotvec(rv).as_matrix().T + t
            out.append(np.c_[fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy])
        return (np.concatenate(out) - obs).ravel()

    res = least_squares(residuals, x0, method="lm")
    fx, fy, cx, cy = res.x[:4]
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    rms = float(np.sqrt(np.mean(res.fun.reshape(-1, 2) ** 2) * 2))
    return k, rms


# ---- scene file ---------------------------------------------------------------------------------


def write_camera_intrinsics(scene: str | Path, out: str | Path, K: np.ndarray, size: tuple[int, int], *,
                            max_aspect_error: float = 0.01) -> Path:
    """Copy ``scene`` to ``out`` with the perspective sensor set to intrinsics ``K`` for (H, W) frames.

    Writes ``fov`` (degrees) with ``fov_axis`` x, ``principal_point_offset_x/y`` (Mitsuba's sign:
    ``offset_x = 1/2 - cx / W``, ``offset_y = 1/2 - cy / H``) and the film's width and height;
    comments and the prolog of the file are kept. Mitsuba's sensor has square pixels, so the
    focal length written is the mean of fx and fy.

    Raises:
        SceneError: the scene has no perspective sensor.
        ValueError: fx and fy differ by more than ``max_aspect_error`` (relative), which a
            square-pixel sensor cannot represent.
    """
    scene, out = Path(scene), Path(out)
    k = np.asarray(K, float)
    hgt, wid = int(size[0]), int(size[1])
    fx, fy = k[0, 0], k[1, 1]
    if abs(fx / fy - 1) > max_aspect_error:
        raise ValueError(f"fx = {fx:.6g} and fy = {fy:.6g} differ by {abs(fx / fy - 1):.2%}; Mitsuba's perspective "
                         f"sensor has square pixels (allowed: {max_aspect_error:.2%})")
    f = (fx + fy) / 2
    def put(parent: ET.Element, tag: str, name: str, value: str) -> None:
        el = next((e for e in parent if e.get("name") == name), None)
        if el is None:
            el = ET.Element(tag, {"name": name})
            parent.insert(0, el)
        el.tag = tag
        el.attrib = {"name": name, "value": value}

    def edit(root: ET.Element) -> None:
        sensors = [s for s in root.iter("sensor") if s.get("type") == "perspective"]
        if not sensors:
            raise SceneError(f"{scene}: no <sensor type=\"perspective\"> (the camera) to write intrinsics into")
        sensor = sensors[0]
        put(sensor, "float", "principal_point_offset_y", f"{0.5 - k[1, 2] / hgt:.12g}")
        put(sensor, "float", "principal_point_offset_x", f"{0.5 - k[0, 2] / wid:.12g}")
        put(sensor, "string", "fov_axis", "x")
        put(sensor, "float", "fov", f"{math.degrees(2 * math.atan(wid / 2 / f)):.12g}")
        film = sensor.find("film")
        if film is None:
            film = ET.SubElement(sensor, "film", {"type": "hdrfilm"})
        put(film, "integer", "height", str(hgt))
        put(film, "integer", "width", str(wid))

    return edit_scene(scene, out, edit)
