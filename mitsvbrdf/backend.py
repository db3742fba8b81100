"""Choose and import the Mitsuba / Dr.Jit backend safely.

Dr.Jit's LLVM backend (``llvm_ad_rgb``, rendering on the CPU) needs a shared libLLVM >= 16. Debian
12 also ships libLLVM 14 and 15, and when Dr.Jit loads 15 the process **aborts** inside LLVM the
first time a kernel uses an instruction it cannot lower (``LLVM ERROR: Cannot select ...
fminimum``): no Python exception, the run just dies. Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` once, when
drjit is imported, so :func:`configure_llvm` must run before that; it finds a library and sets the
variable, or raises :class:`~mitsvbrdf.errors.BackendError`.

libLLVM (:func:`find_libllvm`): ``$DRJIT_LIBLLVM_PATH`` when set, validated and never replaced
(an existing file of LLVM >= 16, else BackendError); otherwise the newest libLLVM >= 16 in
:data:`SEARCH_DIRS`. The version comes from the file name (``libLLVM-17.so.1``,
``libLLVM.so.19.1``) or the name a symbolic link points to, else from the library's own
``LLVMGetVersion`` (absent before LLVM 16), called in a subprocess so that a broken library cannot
crash the caller. If drjit was imported first, the libLLVM it loaded is final: accepted when >= 16,
else BackendError.

Variant (:func:`choose_variant`): the argument, then ``$MITSVBRDF_VARIANT``, then ``cuda_ad_rgb``
when torch sees a CUDA device, else ``llvm_ad_rgb``.

Usage: ``mi = import_mitsuba()`` (configures libLLVM, imports mitsuba, sets the variant).
``python -m mitsvbrdf.backend --check-llvm`` prints the library's path and exits 0, or explains on
stderr and exits 1 (``scripts/setup.sh`` uses it).
"""

from __future__ import annotations

import argparse
import functools
import glob
import os
import platform
import re
import subprocess
import sys
from dataclasses import dataclass
from types import ModuleType

import torch

from .errors import BackendError

MIN_LLVM = 16
"""Oldest libLLVM major version Dr.Jit's LLVM backend works with (15 aborts the process)."""

VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")
"""The Mitsuba variants the renderer runs on: differentiable RGB on the CPU or an NVIDIA GPU."""

ENV_LLVM = "DRJIT_LIBLLVM_PATH"
ENV_VARIANT = "MITSVBRDF_VARIANT"

SEARCH_DIRS = (f"/usr/lib/{platform.machine()}-linux-gnu", "/usr/lib/llvm-*/lib")
"""Folders searched for libLLVM (``*`` expands): Debian's multiarch folder (its ``libllvm19``
package) and the LLVM packages' own folders."""

FIX = (f"install Debian's libllvm19 (apt-get install libllvm19) or set {ENV_LLVM} to a "
       f"libLLVM >= {MIN_LLVM}")
"""How to fix a missing libLLVM, quoted in every error about one."""

# A whole shared libLLVM, not a component such as libLLVMSPIRVLib.so: libLLVM.so, libLLVM-19.so,
# libLLVM-14.0.6.so.1, libLLVM.so.19.1. Group 1 or 2 is the major version when the name has one.
_LIB_NAME = re.compile(r"^libLLVM(?:-(\d+)(?:\.\d+)*)?\.so(?:\.(\d+)(?:\.\d+)*)?$")

_PROBE = r"""
import ctypes, sys
try:
    lib = ctypes.CDLL(sys.argv[1])
except OSError as e:
    sys.exit(f"cannot be loaded: {e}")
if not hasattr(lib, "LLVMGetVersion"):
    sys.exit("has no LLVMGetVersion, so it is older than LLVM 16")
v = [ctypes.c_uint() for _ in range(3)]
lib.LLVMGetVersion(*(ctypes.byref(x) for x in v))
print(v[0].value)
"""


@dataclass(frozen=True)
class LibLLVM:
    """A shared libLLVM on disk.

    Attributes:
        path: file path as found (may be a symbolic link), suitable for ``DRJIT_LIBLLVM_PATH``.
        major: LLVM major version, e.g. 19.
    """

    path: str
    major: int


def parse_llvm_major(filename: str) -> int | None:
    """Major LLVM version carried by a library's file name (or path); None when it carries none
    or does not name a whole shared libLLVM.

    >>> parse_llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-17.so.1"), parse_llvm_major("libLLVM.so.19.1")
    (17, 19)
    >>> parse_llvm_major("libLLVM.so") is None
    True
    """
    m = _LIB_NAME.match(os.path.basename(filename))
    major = m and (m.group(1) or m.group(2))
    return int(major) if major else None


@functools.lru_cache(maxsize=None)
def _probe(realpath: str) -> tuple[int | None, str]:
    """(major or None, what is wrong) of a library, asked in a child process (cached per file)."""
    try:
        r = subprocess.run([sys.executable, "-I", "-c", _PROBE, realpath], capture_output=True,
                           text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as e:
        return None, f"could not be probed ({e})"
    if r.returncode == 0 and r.stdout.strip().isdigit():
        return int(r.stdout), ""
    if r.returncode < 0:
        return None, f"crashed the process that loaded it (signal {-r.returncode})"
    return None, r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}"


def library_version(path: str) -> tuple[int | None, str]:
    """(major or None, why None) of a libLLVM file: from its name, else the name it links to,
    else by loading it in a subprocess (so it cannot crash this process)."""
    major = parse_llvm_major(path) or parse_llvm_major(os.path.realpath(path))
    if major is not None:
        return major, ""
    return _probe(os.path.realpath(path))


def _check_env_library(path: str) -> LibLLVM:
    """Validate the explicitly configured library (``$DRJIT_LIBLLVM_PATH``)."""
    if not os.path.isfile(path):
        raise BackendError(f"{ENV_LLVM}={path} is not an existing file (give the full path of a "
                           f"libLLVM >= {MIN_LLVM}); {FIX}")
    major, why = library_version(path)
    if major is None or major < MIN_LLVM:
        raise BackendError(f"{ENV_LLVM}={path} {why or f'is libLLVM {major}'}, but Dr.Jit's LLVM "
                           f"backend needs libLLVM >= {MIN_LLVM} (older versions abort the process); {FIX}")
    return LibLLVM(path, major)


def find_libllvm() -> LibLLVM | None:
    """A shared libLLVM >= 16 for Dr.Jit, or None when there is none.

    ``$DRJIT_LIBLLVM_PATH`` when set (validated: :class:`BackendError` if it is missing or older),
    else the highest version in :data:`SEARCH_DIRS` (the first found on a tie).

    Raises:
        BackendError: ``$DRJIT_LIBLLVM_PATH`` names a missing, unloadable or old library.
    """
    env = os.environ.get(ENV_LLVM)
    if env:
        return _check_env_library(env)
    best: LibLLVM | None = None
    for folder in SEARCH_DIRS:
        for path in sorted(glob.glob(os.path.join(folder, "libLLVM*.so*"))):
            if _LIB_NAME.match(os.path.basename(path)) is None or not os.path.isfile(path):
                continue
            major, _ = library_version(path)
            if major is not None and major >= MIN_LLVM and (best is None or major > best.major):
                best = LibLLVM(path, major)
    return best


def _loaded_llvm_major() -> int:
    """Major version of the libLLVM an already imported drjit loaded; -1 if none."""
    import drjit as dr  # only called once drjit is imported: importing it here picks no library

    return int(dr.detail.llvm_version()[0])


def configure_llvm() -> LibLLVM:
    """Make Dr.Jit use a libLLVM >= 16; call before drjit or mitsuba is imported.

    Sets ``os.environ["DRJIT_LIBLLVM_PATH"]`` to :func:`find_libllvm`'s choice and returns it.
    If drjit is already imported, the library it loaded is final: returned when >= 16 (its path
    is then what ``DRJIT_LIBLLVM_PATH`` said, possibly ""), else BackendError.

    Raises:
        BackendError: no libLLVM >= 16 exists (the message says how to install one),
            ``$DRJIT_LIBLLVM_PATH`` names a missing or old library, or drjit already loaded an old one.
    """
    if "drjit" in sys.modules:
        major = _loaded_llvm_major()
        if major >= MIN_LLVM:
            return LibLLVM(os.environ.get(ENV_LLVM, ""), major)
        loaded = f"libLLVM {major}" if major > 0 else "no usable libLLVM"
        raise BackendError(
            f"drjit was imported before mitsvbrdf.backend.configure_llvm() and loaded {loaded}; "
            f"Dr.Jit's LLVM backend needs libLLVM >= {MIN_LLVM} (older versions abort the process). "
            f"Call configure_llvm() or import_mitsuba() before importing drjit/mitsuba; {FIX}")
    lib = find_libllvm()
    if lib is None:
        raise BackendError(f"no libLLVM >= {MIN_LLVM} found for Dr.Jit's LLVM backend "
                           f"(searched {', '.join(SEARCH_DIRS)}); {FIX}")
    os.environ[ENV_LLVM] = lib.path
    return lib


def choose_variant(prefer: str | None = None) -> str:
    """The Mitsuba variant to use: ``prefer``, else ``$MITSVBRDF_VARIANT``, else ``cuda_ad_rgb``
    when torch sees a CUDA device, else ``llvm_ad_rgb``.

    Raises:
        BackendError: an explicit choice is not one of :data:`VARIANTS`.
    """
    chosen, origin = (prefer, "variant") if prefer else (os.environ.get(ENV_VARIANT), ENV_VARIANT)
    if chosen:
        if chosen not in VARIANTS:
            raise BackendError(f"unknown Mitsuba variant {chosen!r} (from {origin}); choose one of "
                               f"{', '.join(VARIANTS)}")
        return chosen
    return "cuda_ad_rgb" if torch.cuda.is_available() else "llvm_ad_rgb"


def import_mitsuba(variant: str | None = None) -> ModuleType:
    """Import Mitsuba with a safe libLLVM, set the variant and return the ``mitsuba`` module.

    Args:
        variant: resolved by :func:`choose_variant`. For ``llvm_ad_rgb``, :func:`configure_llvm`
            must succeed; for ``cuda_ad_rgb`` it is tried too (the same process may render on
            the CPU later), and its failure ignored. Idempotent.

    Raises:
        BackendError: no suitable libLLVM for the LLVM variant, mitsuba not installed, or the
            variant unusable here (e.g. ``cuda_ad_rgb`` without an NVIDIA GPU and driver).
    """
    variant = choose_variant(variant)
    try:
        configure_llvm()
    except BackendError:
        if variant.startswith("llvm"):
            raise
    try:
        import mitsuba as mi  # only now: importing it loads drjit, which reads DRJIT_LIBLLVM_PATH
    except ImportError as e:
        raise BackendError(f"mitsuba cannot be imported ({e}); run scripts/setup.sh") from e
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except (ImportError, AttributeError, ValueError, RuntimeError) as e:
            hint = " (it needs an NVIDIA GPU and driver)" if variant.startswith("cuda") else ""
            raise BackendError(f"Mitsuba variant {variant!r} is not usable here{hint}: "
                               f"{str(e).strip().rstrip('.')}. "
                               f"Choose another with {ENV_VARIANT}=... or import_mitsuba(variant=...)"
                               ) from e
    return mi


def main(argv: list[str] | None = None) -> int:
    """``python -m mitsvbrdf.backend --check-llvm``; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m mitsvbrdf.backend",
                                     description="Find the libLLVM Dr.Jit's LLVM backend would use.")
    parser.add_argument("--check-llvm", action="store_true", required=True,
                        help=f"print the path of a libLLVM >= {MIN_LLVM} and exit 0, or exit 1 if none")
    parser.parse_args(argv)
    try:
        lib = find_libllvm()
    except BackendError as e:
        print(e, file=sys.stderr)
        return 1
    if lib is None:
        print(f"no libLLVM >= {MIN_LLVM} found in {', '.join(SEARCH_DIRS)}; {FIX}", file=sys.stderr)
        return 1
    print(lib.path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
