"""Evaluation metrics of reconstructed SVBRDFs (the paper's Tables 1 and 3).

* Map RMSE on the encoded maps (docs/conventions.md: normal as (n + 1) / 2, albedos and roughness as
  stored, all in [0, 1]) per map and their average; the flat-normal RMSE of a set of materials is
  the level a method reaches by predicting no normal detail at all.
* Re-rendering RMSE and SSIM: both materials rendered under the same novel lighting
  (:mod:`mitsvbrdf.relight`), tone-mapped with the ground truth's exposure, compared per image.
* LPIPS only when the ``lpips`` package and its weights are present locally (no downloads).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .svbrdf import ENCODED_SLICES, SVBRDF

#: Each map's channels in the encoded maps the metrics compare.
MAP_CHANNELS = ENCODED_SLICES


def _check_pair(pred: SVBRDF, gt: SVBRDF) -> None:
    if pred.resolution != gt.resolution:
        raise ValueError(f"prediction is {pred.resolution[0]}x{pred.resolution[1]} but the ground truth is "
                         f"{gt.resolution[0]}x{gt.resolution[1]}")
    if pred.batch_size != gt.batch_size:
        raise ValueError(f"prediction has {pred.batch_size} materials, the ground truth {gt.batch_size}")


def map_rmse(pred: SVBRDF, gt: SVBRDF) -> dict[str, Tensor]:
    """RMSE of each encoded map and their mean ("average"), per material: {name: (B,)}."""
    _check_pair(pred, gt)
    a, b = pred.encoded(), gt.encoded()
    out = {k: (a[:, s] - b[:, s]).square().mean((1, 2, 3)).sqrt() for k, s in MAP_CHANNELS.items()}
    out["average"] = torch.stack([out[k] for k in MAP_CHANNELS]).mean(0)
    return out


def flat_normal_rmse(gt: SVBRDF) -> Tensor:
    """Normal RMSE (encoded) of predicting n = (0, 0, 1) everywhere, per material: (B,). A method
    whose normal RMSE sits at this level has not recovered the normals."""
    flat = torch.zeros_like(gt.normal)
    flat[:, 2] = 1.0
    return ((flat - gt.normal) / 2).square().mean((1, 2, 3)).sqrt()


def image_rmse(pred: Tensor, gt: Tensor) -> Tensor:
    """RMSE per material over all its images: (B, L, 3, H, W) -> (B,)."""
    return (pred - gt).square().flatten(1).mean(1).sqrt()


def image_ssim(pred: Tensor, gt: Tensor) -> Tensor:
    """Mean SSIM (scikit-image, 7x7 Gaussian-free window, data range 1) over the L images of each
    material, for display values in [0, 1]: (B, L, 3, H, W) -> (B,)."""
    from skimage.metrics import structural_similarity

    p = pred.detach().cpu().numpy()
    g = gt.detach().cpu().numpy()
    win = min(7, p.shape[-1], p.shape[-2])
    win -= 1 - win % 2  # odd
    out = np.zeros(p.shape[0])
    for b in range(p.shape[0]):
        out[b] = np.mean([structural_similarity(p[b, i], g[b, i], channel_axis=0, data_range=1.0, win_size=win)
                          for i in range(p.shape[1])])
    return torch.from_numpy(out)


def lpips_model():
    """An LPIPS model when the package and its weights are installed locally, else (None, why)."""
    try:
        import lpips  # noqa: F401
    except ImportError:
        return None, "LPIPS skipped: the 'lpips' package is not installed (its weights cannot be downloaded here)"
    try:
        return lpips.LPIPS(net="alex", verbose=False), ""
    except Exception as exc:  # weights missing locally: the package would try to download them
        return None, f"LPIPS skipped: its weights are not available locally ({exc})"
