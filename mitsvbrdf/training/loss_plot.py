"""The loss curves of a training run: ``loss.png`` beside its ``metrics.csv``.

A logged step's loss is one batch of 4 materials at CPU scale, so consecutive values scatter by a
factor of 2-5 and a plot of the raw values hides the trend (docs/evaluation/*/training_runs/).
Each term is drawn twice: the raw values faint, and their trailing running mean over
:func:`smoothing_window` logged steps solid. Trailing rather than centred, so that the curve's
last point is the mean of the steps a run ended with (what ``benchmarks/training_log.py``
reports as "last 10%" at a wider window). Log scale on the loss axis.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: metrics.csv columns that are not loss terms.
NOT_LOSSES = ("step", "lr", "it_per_s", "seconds")


def smoothing_window(n: int) -> int:
    """Logged steps per running mean for a run of ``n`` logged steps: 2% of them, at least 1."""
    return max(1, n // 50)


def running_mean(values, window: int) -> np.ndarray:
    """Trailing mean of ``values`` over the last ``window`` entries, shape ``(len(values),)``.

    Non-finite entries (a term not logged at that step) are left out of every mean; a mean over
    none of them is nan. The first ``window - 1`` means average the entries there are."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    csum = np.concatenate([[0.0], np.cumsum(np.where(ok, v, 0.0))])
    cnt = np.concatenate([[0], np.cumsum(ok)])
    hi = np.arange(1, len(v) + 1)
    lo = np.maximum(hi - window, 0)
    n = cnt[hi] - cnt[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (csum[hi] - csum[lo]) / np.maximum(n, 1), math.nan)


def write_loss_plot(rows: list[dict], path: Path, title: str) -> None:
    """Plot every loss term of ``rows`` (metrics.csv rows: ``step`` and the terms, as numbers or
    strings; a missing or empty value is not logged) against the step into ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def number(x) -> float:
        return math.nan if x is None or x == "" else float(x)

    keys = [k for k in dict.fromkeys(k for r in rows for k in r) if k not in NOT_LOSSES]
    steps = [number(r["step"]) for r in rows]
    window = smoothing_window(len(rows))
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for i, k in enumerate(keys):
        values = [number(r.get(k)) for r in rows]
        colour = f"C{i % 10}"
        ax.plot(steps, values, color=colour, alpha=0.2, linewidth=0.6)
        ax.plot(steps, running_mean(values, window), color=colour, linewidth=1.5, label=k)
    ax.set_xlabel("step")
    ax.set_yscale("log")
    ax.set_title(f"{title} (faint: each logged step; solid: mean of the last {window} logged)", fontsize=8)
    if keys:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
