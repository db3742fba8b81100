"""High dynamic range from exposure brackets: camera response calibration and merging.

A camera maps the exposure X = E t (linear radiance E times exposure time t, in seconds) to a
pixel value z in [0, 1] through an unknown monotonic response, then quantises it. Following
Debevec and Malik (1997), the inverse response is tabulated as g(z_k) = ln X on the camera's L
code levels and recovered from a bracket of the same scene by weighted linear least squares with a
second-difference smoothness prior; ``g`` is fixed up to a constant, pinned by g(mid level) = 0
(radiance is then relative, which is all the renderers need after the LCD's intensity
calibration).

Merging weights each frame's estimate ln E = g(z) - ln t by a hat function of z that falls to 0
at the code extremes, so saturated and noise-floor samples drop out; pixels saturated in every
frame (or dark in every frame) are reported, not guessed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def hat_weight(z: np.ndarray) -> np.ndarray:
    """Weight of a pixel value z in [0, 1]: 0 at the ends, 1 in the middle (triangle)."""
    return np.clip(1.0 - np.abs(2.0 * z - 1.0), 0.0, 1.0)


@dataclass(frozen=True)
class Response:
    """Inverse camera response on ``levels`` codes: ``log_exposure[k] = ln X`` for code k / (levels - 1)."""

    log_exposure: np.ndarray

    @property
    def levels(self) -> int:
        return self.log_exposure.shape[0]

    def codes(self, z: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(np.asarray(z) * (self.levels - 1)), 0, self.levels - 1).astype(np.int64)

    def exposure(self, z: np.ndarray) -> np.ndarray:
        """Relative exposure X for pixel values z in [0, 1]."""
        return np.exp(self.log_exposure[self.codes(z)])

    def pixel_value(self, exposure: np.ndarray) -> np.ndarray:
        """The forward response: pixel values z in [0, 1] for relative exposures X >= 0: the code
        whose ln X is nearest (midpoints in ln X); exposures beyond the table clip to the end codes."""
        with np.errstate(divide="ignore"):
            log_x = np.log(np.maximum(np.asarray(exposure, dtype=np.float64), 0.0))
        g = np.maximum.accumulate(self.log_exposure)  # a fitted g may wiggle by rounding; keep it monotonic
        code = np.searchsorted(0.5 * (g[1:] + g[:-1]), log_x)  # the code whose g is nearest to ln X
        return code / (self.levels - 1)

    @classmethod
    def gamma(cls, gamma: float = 2.2, levels: int = 256) -> "Response":
        """The response z = X^(1 / gamma) (exposure 1 at z = 1), for known cameras and tests."""
        z = np.arange(levels) / (levels - 1)
        with np.errstate(divide="ignore"):
            g = gamma * np.log(np.maximum(z, 0.5 / (levels - 1)))
        return cls(g)


def calibrate_response(values: np.ndarray, exposure_times: np.ndarray, *, levels: int = 256,
                       smoothness: float = 50.0) -> Response:
    """Recover the inverse response from a bracket.

    Args:
        values: (K, N) pixel values in [0, 1] of the same N scene points in K frames (pick N of a
            few hundred points spread over the radiance range).
        exposure_times: (K,) seconds.
        smoothness: weight of the second-difference prior on g.
    Returns:
        the :class:`Response`, normalised so that g at the middle code is 0.
    """
    values = np.asarray(values, dtype=np.float64)
    t = np.asarray(exposure_times, dtype=np.float64)
    if values.ndim != 2 or values.shape[0] != t.shape[0] or values.shape[0] < 2:
        raise ValueError(f"values must be (K, N) for K >= 2 exposure times, got {values.shape} and {t.shape}")
    if (t <= 0).any():
        raise ValueError("exposure times must be positive")
    k, n = values.shape
    z = np.clip(np.rint(values * (levels - 1)), 0, levels - 1).astype(np.int64)
    w = hat_weight(z / (levels - 1)) + 1e-3  # keep every equation, trust the middle codes most
    rows = k * n + (levels - 2) + 1
    a = np.zeros((rows, levels + n))
    b = np.zeros(rows)
    r = np.arange(k * n)
    a[r, z.reshape(-1)] = w.reshape(-1)
    a[r, levels + np.tile(np.arange(n), k)] = -w.reshape(-1)
    b[r] = w.reshape(-1) * np.repeat(np.log(t), n)
    # smoothness: g[i-1] - 2 g[i] + g[i+1] = 0, weighted like the data
    for i in range(1, levels - 1):
        row = k * n + i - 1
        wi = smoothness * hat_weight(np.array(i / (levels - 1)))
        a[row, i - 1: i + 2] = wi * np.array([1.0, -2.0, 1.0])
    a[-1, levels // 2] = 1.0  # pin the scale: g(mid) = 0
    sol = np.linalg.lstsq(a, b, rcond=None)[0]
    return Response(sol[:levels])


@dataclass
class HDRResult:
    """radiance (H, W, C) relative linear radiance (NaN where unknown); saturated / dark: (H, W, C)
    masks of samples that were clipped high / at the noise floor in every frame."""

    radiance: np.ndarray
    saturated: np.ndarray
    dark: np.ndarray


def merge_hdr(frames: np.ndarray, exposure_times: np.ndarray, response: Response, *,
              low: float = 0.02, high: float = 0.98) -> HDRResult:
    """Merge frames (K, H, W, C) in [0, 1] taken with ``exposure_times`` (K,) seconds."""
    frames = np.asarray(frames, dtype=np.float64)
    t = np.asarray(exposure_times, dtype=np.float64)
    if frames.ndim != 4 or frames.shape[0] != t.shape[0]:
        raise ValueError(f"frames must be (K, H, W, C) with K = {t.shape[0]} exposure times, got {frames.shape}")
    w = hat_weight(frames) * ((frames > low) & (frames < high))
    log_e = response.log_exposure[response.codes(frames)] - np.log(t)[:, None, None, None]
    wsum = w.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        radiance = np.exp((w * log_e).sum(0) / wsum)
    radiance[wsum <= 0] = np.nan
    return HDRResult(radiance, (frames >= high).all(0), (frames <= low).all(0))
