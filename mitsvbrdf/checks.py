"""Checks of user-given values that run before any work starts (the CLI's and the library's).

Each raises :class:`~mitsvbrdf.errors.MitsvbrdfError` with one line naming the value and what
is allowed, so that ``mitsvbrdf`` prints ``mitsvbrdf: error: ...`` and exits 2 before it renders
anything or creates a folder.
"""

from __future__ import annotations

import math
import numbers
from pathlib import Path

from .errors import MitsvbrdfError

#: Sampler seeds are Dr.Jit UInt32 values.
SEED_MAX = 2 ** 32 - 1


def check_int(name: str, value: object, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int within [low, high] (either bound may be None)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):  # also numpy integers
        value = int(value)
    elif isinstance(value, float) and value.is_integer():
        value = int(value)
    else:
        raise MitsvbrdfError(f"{name} must be a whole number, got {value!r}")
    if low is not None and value < low or high is not None and value > high:
        raise MitsvbrdfError(f"{name} must be {_range(low, high)}, got {value}")
    return value


def check_float(name: str, value: object, low: float | None = None, high: float | None = None, *,
                low_open: bool = False) -> float:
    """``value`` as a finite float within [low, high] ((low, high] with ``low_open``)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise MitsvbrdfError(f"{name} must be a number, got {value!r}") from None
    bad_low = low is not None and (v <= low if low_open else v < low)
    if not math.isfinite(v) or bad_low or high is not None and v > high:
        what = _range(low, high, low_open) if low is not None or high is not None else "a finite number"
        raise MitsvbrdfError(f"{name} must be {what}, got {value}")
    return v


def check_seed(name: str, value: object, count: int = 1) -> int:
    """A sampler seed: ``value`` .. ``value + count - 1`` must all be UInt32 values."""
    return check_int(name, value, 0, SEED_MAX - (count - 1))


def _range(low, high, low_open: bool = False) -> str:
    if low is not None and high is not None:
        return f"in {'(' if low_open else '['}{low}, {high}]"
    if low is not None:
        return f"{'>' if low_open else '>='} {low}"
    return f"<= {high}"


def check_out_dir(name: str, path: str | Path) -> Path:
    """An output folder that can be created (or exists as a folder): not a file, nor under one."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise MitsvbrdfError(f"{name} {str(p)!r} is a file, not a folder")
    _check_parents(name, p)
    return p


def check_out_file(name: str, path: str | Path) -> Path:
    """An output file that can be written: not a folder, and no file where a parent folder goes."""
    p = Path(path)
    if p.is_dir():
        raise MitsvbrdfError(f"{name} {str(p)!r} is a folder, expected a file name")
    _check_parents(name, p)
    return p


def _check_parents(name: str, p: Path) -> None:
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise MitsvbrdfError(f"{name} {str(p)!r} lies under {str(parent)!r}, which is a file")
            return
