"""Contact sheets of SVBRDFs: the four maps and a reference rendering per material, for looking.

One material is a row of five tiles ``[normal | diffuse | roughness | specular | render]``; rows
are laid out in ``columns`` side-by-side groups. Maps are shown as stored (normal encoded as
(n + 1) / 2, the others as values in [0, 1]); the rendering is the reference renderer's image under
one pattern (default: uniform white), tone-mapped with one exposure for the whole sheet
(:func:`mitsvbrdf.viewing.tonemap`), so relative brightness between materials stays visible.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from ..render import QuadratureSettings, render
from ..svbrdf import SVBRDF
from ..viewing import tonemap

LABEL_HEIGHT = 12


def contact_sheet(svbrdf: SVBRDF, renders: Tensor | None = None, *, tile: int = 128, columns: int = 2,
                  labels: list[str] | None = None) -> np.ndarray:
    """Lay out B materials as an (rows * (tile + label), columns * 5 * tile, 3) float image in [0, 1].

    ``renders`` (B, 3, h, w) are linear; they are tone-mapped together (one exposure).
    Without renders, rows have four tiles. ``labels`` (one per material) are drawn above each row.
    """
    m = svbrdf.detach().to("cpu").resized(tile)
    tiles = [(m.normal + 1) / 2, m.diffuse, m.roughness.expand(-1, 3, -1, -1), m.specular]
    if renders is not None:
        r = renders.detach().cpu().float()
        if r.shape[-1] != tile:
            r = torch.nn.functional.interpolate(r, size=(tile, tile), mode="area" if r.shape[-1] > tile else "bilinear")
        tiles.append(tonemap(r))
    row_imgs = torch.cat(tiles, dim=-1).clamp(0, 1)  # (B, 3, tile, k * tile)
    B = row_imgs.shape[0]
    lab = LABEL_HEIGHT if labels else 0
    rows = math.ceil(B / columns)
    gap = 4
    rw = row_imgs.shape[-1]
    sheet = np.ones((rows * (tile + lab + gap), columns * (rw + gap), 3), dtype=np.float32)
    for b in range(B):
        rr, cc = divmod(b, columns)
        y0, x0 = rr * (tile + lab + gap) + lab, cc * (rw + gap)
        sheet[y0:y0 + tile, x0:x0 + rw] = row_imgs[b].permute(1, 2, 0).numpy()
    if labels:
        sheet = _draw_labels(sheet, labels, columns, tile + lab + gap, rw + gap)
    return sheet


def _draw_labels(sheet: np.ndarray, labels: list[str], columns: int, row_h: int, col_w: int) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(np.round(sheet * 255).astype(np.uint8))
    draw = ImageDraw.Draw(im)
    for b, text in enumerate(labels):
        rr, cc = divmod(b, columns)
        draw.text((cc * col_w + 2, rr * row_h), text, fill=(0, 0, 0))
    return np.asarray(im, dtype=np.float32) / 255


def render_previews(svbrdf: SVBRDF, rig, patterns: Tensor, *, size: int = 128,
                    progress: Callable[[int], None] | None = None) -> Tensor:
    """Reference renders (B, 3, size, size) of each material under ``patterns[0]``.

    Uses a coarse quadrature (1 Gauss point per cell, 8 x 8 lobe points), about 0.3 % of the peak
    off the default settings on typical materials, for speed; materials render one by one.
    """
    settings = QuadratureSettings(cell_order=1, lobe_grid=8)
    small = svbrdf.detach().resized(size)
    out = []
    with torch.no_grad():
        for b in range(small.batch_size):
            out.append(render(small[b], patterns[:1], rig, settings=settings)[0, 0])
            if progress is not None:
                progress(1)
    return torch.stack(out)
