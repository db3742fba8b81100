"""Exceptions raised by mitsvbrdf.

Every error derives from :class:`MitsvbrdfError` (a ``ValueError``) so callers can catch the
library's own complaints about bad input in one place; messages name the offending file, map or
parameter and say what was expected.
"""

from __future__ import annotations


class MitsvbrdfError(ValueError):
    """Base class of all mitsvbrdf input errors."""


class MaterialError(MitsvbrdfError):
    """SVBRDF maps with a wrong shape, range, NaN or non-unit normals."""


class ImageFileError(MitsvbrdfError):
    """An image/EXR file that is missing, truncated, corrupt or of an unsupported layout."""


class SceneError(MitsvbrdfError):
    """A scene file that is missing, malformed or lacks a required element (camera, LCD, sample)."""


class PatternError(MitsvbrdfError):
    """Patterns of the wrong shape, with NaN, or with drive values outside [0, 1]."""


class ImageError(MitsvbrdfError):
    """Images (renders or captures) of the wrong shape, or with NaN/Inf values."""


class BackendError(RuntimeError):
    """No usable Dr.Jit backend (e.g. no libLLVM >= 16 for the LLVM variant)."""
