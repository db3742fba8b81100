"""Pattern families for the LCD: drive values in [0, 1], shaped (P, 3, h, w).

Cell coordinates: u = (column + 1/2) / w runs along the LCD's columns (corner 0 -> 1), v = (row + 1/2) / h
along its rows (corner 0 -> 3); see :mod:`mitsvbrdf.rig`. "x" and "y" gradients below are
gradients in u and v.

Families:
    uniform      one constant pattern (default white).
    monograd     5 monochrome gradients (Ghosh et al. 2010 style): constant, u, v, 1-u, 1-v.
    colorgrad    5 coloured gradients (Fyffe 2015 style): white, RGB = (u, v, z), its complement
                 (1-u, 1-v, 1-z), and the channel-rotated pair (v, z, u), (1-v, 1-z, 1-u), where
                 z = 1 - (x^2 + y^2) / 2 with x = 2u - 1, y = 2v - 1 is the planar stand-in for the
                 spherical z gradient (1 at the LCD centre, 0 at its corners). The rotated pair makes
                 every channel see every gradient, so the group has the 5 patterns a capture uses.
    step_edges   n step edges for re-rendering evaluation: half the patterns switch from 0 to 1
                 along u at evenly spaced positions, the other half along v.
    picked       5 hand-picked patterns (the paper's "Picked" group, with our own picks, since the
                 published learned patterns are not available): white, a white half (u < 1/2), and
                 three colour patterns with large colour variation: a hue sweep along u, a hue
                 sweep along v, and an RGB checker of 4 x 4 blocks.
    random       i.i.d. uniform drive values from a seeded generator.

Data-driven groups: :func:`pca_patterns` turns L_pdf maps of many materials into the paper's "PCA"
group (mean and principal components, affinely mapped to [0, 1]).
"""

from __future__ import annotations

import numbers
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .errors import PatternError
from .imageio import read_image

FAMILIES = ("uniform", "monograd", "colorgrad", "step_edges", "picked", "random")


def _uv(h: int, w: int) -> tuple[Tensor, Tensor]:
    v, u = torch.meshgrid((torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w, indexing="ij")
    return u, v


def _grey(t: Tensor) -> Tensor:
    return t.expand(3, *t.shape)


def uniform(h: int = 32, w: int = 32, value: float = 1.0) -> Tensor:
    """(1, 3, h, w) constant pattern."""
    if not 0.0 <= value <= 1.0:
        raise PatternError(f"uniform pattern value must lie in [0, 1], got {value}")
    return torch.full((1, 3, h, w), float(value))


def monograd(h: int = 32, w: int = 32) -> Tensor:
    """(5, 3, h, w) monochrome gradients: constant, u, v, 1 - u, 1 - v."""
    u, v = _uv(h, w)
    return torch.stack([_grey(torch.ones_like(u)), _grey(u), _grey(v), _grey(1 - u), _grey(1 - v)])


def colorgrad(h: int = 32, w: int = 32) -> Tensor:
    """(5, 3, h, w) coloured gradients: white, (u, v, z), complement, (v, z, u), complement."""
    u, v = _uv(h, w)
    z = 1.0 - ((2 * u - 1) ** 2 + (2 * v - 1) ** 2) / 2
    g = torch.stack([u, v, z])
    r = torch.stack([v, z, u])
    return torch.stack([torch.ones(3, h, w), g, 1 - g, r, 1 - r])


def step_edges(h: int = 32, w: int = 32, n: int = 10) -> Tensor:
    """(n, 3, h, w) white/black step edges: ceil(n/2) along u, the rest along v, edges evenly spaced."""
    if n < 1:
        raise PatternError(f"step_edges needs n >= 1, got {n}")
    u, v = _uv(h, w)
    nu = (n + 1) // 2
    nv = n - nu
    out = [_grey((u > (k + 1) / (nu + 1)).float()) for k in range(nu)]
    out += [_grey((v > (k + 1) / (nv + 1)).float()) for k in range(nv)]
    return torch.stack(out)


def _hue(t: Tensor) -> Tensor:
    """(3, h, w) fully saturated hues for t in [0, 1] (h, w)."""
    k = torch.arange(3, dtype=t.dtype).view(3, 1, 1)
    return (1.0 - (((6.0 * t[None] + 4.0 * k) % 6.0 - 3.0).abs() - 1.0).clamp(0.0, 1.0))


def picked(h: int = 32, w: int = 32) -> Tensor:
    """(5, 3, h, w): white, white half u < 1/2, hue sweep along u, along v, RGB 4 x 4 checker."""
    u, v = _uv(h, w)
    block = ((u * 4).floor() + (v * 4).floor()).long() % 3
    checker = torch.stack([(block == c).float() for c in range(3)])
    return torch.stack([torch.ones(3, h, w), _grey((u < 0.5).float()), _hue(u), _hue(v), checker])


def pca_patterns(lpdf: Tensor, n: int = 5) -> Tensor:
    """The "PCA" group from L_pdf maps (N, 1, h, w) (or (N, h, w)) of N materials: (n, 3, h, w) grey.

    Pattern 0 is the mean L_pdf, patterns 1.. the leading principal components of the centred
    maps; each is mapped affinely to [0, 1] (a component's sign is arbitrary, so it is fixed to
    make the brightest cell positive).
    """
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise PatternError(f"PCA patterns: the count must be a whole number >= 1, got {n!r}")
    x = lpdf.reshape(lpdf.shape[0], -1).double()
    if x.shape[0] < n:
        raise PatternError(f"PCA of {n} patterns needs at least {n} L_pdf maps, got {x.shape[0]}")
    mean = x.mean(0)
    _, _, vt = torch.linalg.svd(x - mean, full_matrices=False)
    comps = [mean] + [c * torch.sign(c[c.abs().argmax()]) for c in vt[: n - 1]]
    hw = lpdf.shape[-2:]
    out = []
    for c in comps:
        c = (c - c.min()) / (c.max() - c.min()).clamp_min(1e-12)
        out.append(_grey(c.float().reshape(hw)))
    return torch.stack(out)


def random(h: int = 32, w: int = 32, n: int = 5, seed: int = 0) -> Tensor:
    """(n, 3, h, w) i.i.d. uniform drive values; the same seed gives the same patterns."""
    g = torch.Generator().manual_seed(int(seed))
    return torch.rand((n, 3, h, w), generator=g)


def pattern_family(name: str, h: int = 32, w: int = 32, **kwargs) -> Tensor:
    """Patterns of a named family (see the module docstring) on an h x w LCD."""
    builders = {"uniform": uniform, "monograd": monograd, "colorgrad": colorgrad,
                "step_edges": step_edges, "picked": picked, "random": random}
    if name not in builders:
        raise PatternError(f"unknown pattern family {name!r}; known: {', '.join(FAMILIES)}")
    return builders[name](h, w, **kwargs)


def prepend_pattern(first: Tensor, rest: Tensor) -> Tensor:
    """One pattern (3, h, w) shown before each material's patterns (B, P, 3, h, w) -> (B, P + 1, 3, h, w):
    L_0 before the adaptive patterns."""
    return torch.cat([first.to(rest)[None, None].expand(rest.shape[0], 1, *first.shape), rest], 1)


def load_pattern(spec: str, h: int = 32, w: int = 32) -> Tensor:
    """One (3, h, w) pattern: ``NAME`` is the first of :func:`load_patterns`'s group (a family name
    or a file), ``NAME[k]`` its k-th (from 0), e.g. ``"colorgrad[1]"``, the (u, v, z) gradient."""
    s, index = str(spec), 0
    if s.endswith("]") and "[" in s:
        s, _, k = s[:-1].rpartition("[")
        if not k.isdigit():
            raise PatternError(f"{spec!r}: the index in brackets must be a whole number >= 0, got {k!r}")
        index = int(k)
    group = load_patterns(s, h, w)
    if index >= group.shape[0]:
        raise PatternError(f"{spec!r}: {s!r} holds {group.shape[0]} patterns (indices 0-{group.shape[0] - 1})")
    return group[index]


def load_patterns(name_or_path: str | Path, h: int = 32, w: int = 32) -> Tensor:
    """A family name, or a file: ``.npy``/``.pt`` holding (P, 3, h, w) (or (3, h, w)) drive values,
    or an image (PNG/EXR) of P tiles of h x w cells side by side (drive values as stored)."""
    s = str(name_or_path)
    if s in FAMILIES:
        return pattern_family(s, h, w)
    path = Path(s)
    if not path.exists():
        raise PatternError(f"{s!r} is neither a pattern family ({', '.join(FAMILIES)}) nor an existing file")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            t = torch.from_numpy(np.load(path, allow_pickle=False)).float()
        except (ValueError, OSError) as e:
            raise PatternError(f"{path}: cannot read patterns from .npy ({e})") from e
    elif suffix == ".pt":
        try:
            t = torch.load(path, weights_only=True)
        except Exception as e:  # not a torch file, truncated, or pickled objects that are not tensors
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise PatternError(f"{path}: cannot read patterns from .pt ({type(e).__name__}: {first})") from e
        if not isinstance(t, Tensor):
            raise PatternError(f"{path}: expected a tensor, found {type(t).__name__}")
        t = t.float()
    else:
        img = torch.from_numpy(read_image(path)).float()  # (rows, cols, C)
        if img.shape[-1] == 1:
            img = img.expand(*img.shape[:2], 3)
        img = img[..., :3]
        rows, cols = img.shape[:2]
        if rows != h or cols % w != 0:
            raise PatternError(f"{path}: a pattern strip must be {h} rows by a multiple of {w} "
                               f"columns (P tiles of {h}x{w} cells), got {rows}x{cols}")
        t = img.reshape(h, cols // w, w, 3).permute(1, 3, 0, 2)
    if t.ndim == 3:
        t = t.unsqueeze(0)
    if t.ndim != 4 or tuple(t.shape[1:]) != (3, h, w):
        raise PatternError(f"{path}: patterns must be (P, 3, {h}, {w}), got {tuple(t.shape)}")
    if t.shape[0] == 0:
        raise PatternError(f"{path}: the file holds no patterns (shape {tuple(t.shape)}); P must be >= 1")
    return t.contiguous()
