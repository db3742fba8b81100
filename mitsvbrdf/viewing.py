"""Pictures for people: the sRGB curve, the one tone-mapping policy, pattern strips, figures, HTML.

(Not to be confused with :mod:`mitsvbrdf.capture.display`, the physical LCD of the bench.)

Tone mapping, everywhere the package shows linear radiance (previews, figures, the re-rendering
metrics' display values): each *set* of images gets one exposure that puts the 99th percentile
of its finite values at 1 (:func:`auto_exposure`); values are then clipped to [0, 1] and
sRGB-encoded (:func:`srgb_encode`). A set whose 99th percentile is 0 is exposed by its maximum
instead, and an all-black set by 1; NaN shows black and +Inf white. Images shown side by side
for comparison share the exposure of the reference set (pass ``exposure``).

Arrays: torch tensors or numpy arrays of any shape; images (..., 3, H, W) in torch, (H, W, 3) in
numpy, as elsewhere in the package.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch import Tensor

from .metrics import MAP_CHANNELS

#: Quantiles are taken on at most this many values (an even stride through larger sets).
QUANTILE_SAMPLES = 1_000_000


def srgb_encode(x: Tensor | np.ndarray) -> Tensor | np.ndarray:
    """Linear values -> sRGB-encoded display values, both in [0, 1] (inputs are clipped first)."""
    if isinstance(x, Tensor):
        x = x.clamp(0.0, 1.0)
        return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(1e-12) ** (1 / 2.4) - 0.055)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 1e-12), 1 / 2.4) - 0.055)


def _set_exposure(values: Tensor) -> float:
    v = values.detach().flatten().float()
    v = v[torch.isfinite(v)]
    if v.numel() == 0:
        return 1.0
    q = float(torch.quantile(v[:: max(1, -(-v.numel() // QUANTILE_SAMPLES))], 0.99))
    if q <= 0:
        q = float(v.max())
    return 1.0 / q if q > 0 else 1.0


def auto_exposure(images: Tensor | np.ndarray, *, per_image: bool = False) -> float | Tensor:
    """The exposure of the policy (module docstring): one float for the whole set, or with
    ``per_image`` one per entry of the first dimension, a tensor (N,)."""
    t = torch.as_tensor(images)
    if per_image:
        return torch.tensor([_set_exposure(im) for im in t], dtype=torch.float32, device=t.device)
    return _set_exposure(t)


def tonemap(images: Tensor | np.ndarray, exposure: float | Tensor | None = None) -> Tensor | np.ndarray:
    """Linear radiance -> display values in [0, 1], same type and shape: ``srgb(clip(exposure x))``
    with :func:`auto_exposure` of the whole set when ``exposure`` is None. NaN shows 0, +Inf 1."""
    if exposure is None:
        exposure = auto_exposure(images)
    if isinstance(images, Tensor):
        x = torch.nan_to_num(images * exposure, nan=0.0, posinf=1.0, neginf=0.0)
    else:
        x = np.nan_to_num(np.asarray(images, dtype=np.float64) * exposure, nan=0.0, posinf=1.0, neginf=0.0)
    return srgb_encode(x)


def to_uint8(display: Tensor | np.ndarray) -> np.ndarray:
    """Display values in [0, 1] -> uint8 codes (rounded)."""
    a = display.detach().cpu().numpy() if isinstance(display, Tensor) else np.asarray(display)
    return np.round(np.clip(a, 0.0, 1.0) * 255).astype(np.uint8)


def hwc(image: Tensor) -> np.ndarray:
    """(3, H, W) or (1, H, W) values -> an (H, W, 3) float array, clipped to [0, 1]."""
    t = image.detach().float().cpu().clamp(0, 1)
    if t.shape[0] == 1:
        t = t.expand(3, *t.shape[1:])
    return t.permute(1, 2, 0).numpy()


def pattern_strip(patterns: Tensor) -> np.ndarray:
    """Patterns or images (P, 3, h, w) side by side: an (h, P * w, 3) array."""
    p = patterns.detach().cpu()
    return p.permute(2, 0, 3, 1).reshape(p.shape[2], -1, 3).numpy()


def write_html_page(path: str | Path, title: str, *, paragraphs: Sequence[str] = (),
                    table: tuple[Sequence[str], Sequence[Sequence]] | None = None,
                    images: Sequence[tuple[str, str]] = ()) -> None:
    """A self-contained report page: a title, paragraphs of text, a table (header, rows) and
    images (caption, relative file), each image under its caption. Every text is escaped."""
    parts = [f"<h1>{html.escape(title)}</h1>"]
    parts += [f"<p>{html.escape(p)}</p>" for p in paragraphs if p]
    if table is not None:
        head, rows = table
        cells = "".join(f"<th>{html.escape(str(h))}</th>" for h in head)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in r) + "</tr>" for r in rows)
        parts.append(f"<table><tr>{cells}</tr>{body}</table>")
    parts += [f'<h2>{html.escape(c)}</h2><img src="{html.escape(f)}" style="max-width:100%">' for c, f in images]
    Path(path).write_text("<!doctype html><html><head><meta charset='utf-8'>"
                          f"<title>{html.escape(title)}</title></head><body>{''.join(parts)}</body></html>\n")


def material_figure(gt, shown: dict, gt_relit: Tensor, path: str | Path) -> None:
    """One PNG per material: per method a row of patterns + captured images, the maps (ground truth
    row first), error maps, and re-renderings (ground truth row first).

    Args:
        gt: the ground-truth SVBRDF (B = 1).
        shown: {method name: (:class:`~mitsvbrdf.acquisition.Acquisition`, its display-value
            re-renderings (L, 3, H, W))}.
        gt_relit: the ground truth's display-value re-renderings (L, 3, H, W).
    """
    import matplotlib  # optional and slow to import: only figures need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(MAP_CHANNELS)
    n_relit = min(4, gt_relit.shape[0])
    rows = 1 + 3 * len(shown)
    cols = max(10, len(names) + n_relit)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 1.3, rows * 1.4))
    for ax in axes.flat:
        ax.axis("off")
    enc_gt = gt.encoded()[0]

    def put(r, c, img, title=""):
        ax = axes[r, c]
        ax.axis("on")  # keep the frame: a white pattern must not vanish into the page
        ax.set_xticks([])
        ax.set_yticks([])
        ax.imshow(img)
        ax.set_title(title, fontsize=6)

    for c, k in enumerate(names):
        put(0, c, hwc(enc_gt[MAP_CHANNELS[k]]), f"GT {k}")
    for c in range(n_relit):
        put(0, len(names) + c, hwc(gt_relit[c]), "GT relit")
    for m, (name, (acq, relit)) in enumerate(shown.items()):
        r0 = 1 + 3 * m
        p = acq.patterns.shape[0]
        exposure = auto_exposure(acq.images)
        for c in range(min(p, cols // 2)):
            put(r0, 2 * c, hwc(acq.patterns[c]), f"{name}: L{c}")
            put(r0, 2 * c + 1, hwc(tonemap(acq.images[c], exposure)), f"I{c}")
        enc = acq.svbrdf.encoded()[0]
        for c, k in enumerate(names):
            put(r0 + 1, c, hwc(enc[MAP_CHANNELS[k]]), f"{name} {k}")
            diff = enc[MAP_CHANNELS[k]] - enc_gt[MAP_CHANNELS[k]]
            put(r0 + 2, c, hwc(diff.abs().mean(0, keepdim=True) * 4),
                f"|error| x4 (rmse {float(diff.square().mean().sqrt()):.3f})")
        for c in range(n_relit):
            put(r0 + 1, len(names) + c, hwc(relit[c]), "relit")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
