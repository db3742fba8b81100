"""Choose and import the Mitsuba / Dr.Jit backend safely.

Why this module exists
----------------------
Dr.Jit's LLVM backend (the ``llvm_*`` Mitsuba variants, i.e. rendering on the CPU) loads a shared
libLLVM and needs version 16 or newer. Debian 12 ships libLLVM-14 and libLLVM-15 as well, and when
Dr.Jit ends up with 15 the whole process **aborts** inside LLVM the first time a kernel uses an
instruction LLVM 15 cannot lower (``LLVM ERROR: Cannot select: ... fminimum``, e.g. from
``dr.minimum``) -- no Python exception, nothing to catch, a test run or a training job just dies.
Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` once, *when drjit is imported*; changing it later has no
effect. So before drjit is imported we find a suitable library ourselves, point
``DRJIT_LIBLLVM_PATH`` at it, and refuse with a clear :class:`~mitsvbrdf.errors.BackendError`
rather than let Dr.Jit run on an old one.

Order of precedence
-------------------
libLLVM (:func:`find_libllvm`):

1. ``$DRJIT_LIBLLVM_PATH`` when set. It is the user's explicit choice, so it is validated, never
   silently replaced: it must be an existing file of LLVM >= 16, else BackendError.
2. The libraries that ``ldconfig -p`` lists (matching this machine's architecture).
3. Globs in common install folders (``/usr/lib/<triplet>``, ``/usr/lib/llvm-*/lib``,
   ``/usr/local/lib``, ``/usr/lib64``, ``/opt/homebrew/opt/llvm/lib``).

Among 2 and 3 the highest major version >= 16 wins (the first one found on a tie). The version
comes from the file name (``libLLVM-17.so.1``, ``libLLVM.so.19.1``, ``libLLVM-14.0.6.so.1``) or,
for a plain ``libLLVM.so`` / ``libLLVM.dylib``, from the name of the file a symbolic link points
to, else from the library itself: ``LLVMGetVersion`` (present since LLVM 16; a library without it
is too old) is called in a *subprocess*, so that a broken library can never crash the caller.

If drjit was imported before :func:`configure_llvm` runs, its choice is final: the library it
loaded (``drjit.detail.llvm_version()``) is accepted when it is >= 16, else BackendError says to
configure the backend before importing drjit/mitsuba.

Mitsuba variant (:func:`choose_variant`): the ``prefer`` / ``variant`` argument, then
``$MITSVBRDF_VARIANT``, then ``cuda_ad_rgb`` when torch sees a CUDA device, else ``llvm_ad_rgb``.

Usage::

    from mitsvbrdf.backend import import_mitsuba, torch_device_for
    mi = import_mitsuba()                 # configures libLLVM, imports mitsuba, sets the variant
    device = torch_device_for(mi.variant())

Command line: ``python -m mitsvbrdf.backend`` prints a report (variant, libLLVM, CUDA) and exits
0; ``python -m mitsvbrdf.backend --check-llvm`` prints the library's path and exits 0 when a
libLLVM >= 16 exists, else explains on stderr and exits 1 (``scripts/setup.sh`` uses it).

This module imports neither torch nor mitsuba/drjit at import time; they are imported lazily.
"""

from __future__ import annotations

import functools
import glob
import os
import platform
import re
import subprocess
import sys
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Iterable

from .errors import BackendError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import torch

MIN_LLVM = 16
"""Oldest libLLVM major version Dr.Jit's LLVM backend works with (15 aborts the process)."""

VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb", "cuda_rgb", "llvm_rgb")
"""Mitsuba variants this project may run on (RGB only; ``_ad_`` ones are differentiable)."""

ENV_LLVM = "DRJIT_LIBLLVM_PATH"
ENV_VARIANT = "MITSVBRDF_VARIANT"

SEARCH_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib/llvm-*/lib",
               "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/lib64")
"""Folders globbed for libLLVM after ``ldconfig -p`` (``*`` expands)."""

LIB_PATTERNS = ("libLLVM-[0-9]*.so*", "libLLVM.so.[0-9]*", "libLLVM.so", "libLLVM-[0-9]*.dylib",
                "libLLVM.dylib")
"""File-name globs of a shared libLLVM in each search folder."""

FIX = (f"install Debian's libllvm19 (apt-get install libllvm19) or set {ENV_LLVM} to a "
       f"libLLVM >= {MIN_LLVM}")
"""How to fix a missing libLLVM, quoted in every error about one."""

# A shared libLLVM file name: libLLVM-19.so, libLLVM-14.0.6.so.1, libLLVM.so.19.1, libLLVM.so,
# libLLVM.dylib, libLLVM-19.dylib -- but not component libraries such as libLLVMSPIRVLib.so.
_LIB_NAME = re.compile(r"^libLLVM(?:-\d+(?:\.\d+)*)?(?:\.so(?:\.\d+)*|\.dylib)$")
_MAJOR_PATTERNS = (re.compile(r"^libLLVM-(\d+)(?:\.\d+)*\.(?:so|dylib)"),
                   re.compile(r"^libLLVM\.so\.(\d+)"))
# ldconfig's architecture tag for 64-bit libraries of this machine ("(libc6,x86-64)").
_LDCONFIG_TAGS = {"x86_64": "x86-64", "amd64": "x86-64", "aarch64": "AArch64", "arm64": "AArch64"}

_PROBE = r"""
import ctypes, sys
try:
    lib = ctypes.CDLL(sys.argv[1])
except OSError as e:
    print("cannot be loaded:", e)
    sys.exit(2)
try:
    get = lib.LLVMGetVersion
except AttributeError:
    print("has no LLVMGetVersion, so it is older than LLVM 16")
    sys.exit(3)
v = [ctypes.c_uint() for _ in range(3)]
get(*(ctypes.byref(x) for x in v))
print("%d.%d.%d" % tuple(x.value for x in v))
"""


@dataclass(frozen=True)
class LibLLVM:
    """A shared libLLVM on disk and its major version.

    Attributes:
        path: file path as found (may be a symbolic link), suitable for ``DRJIT_LIBLLVM_PATH``.
        major: LLVM major version, e.g. 19.
        source: where it was found: ``"DRJIT_LIBLLVM_PATH"``, ``"ldconfig"``, ``"search"`` or
            ``"drjit"`` (already loaded by an imported drjit); informational, not compared.
    """

    path: str
    major: int
    source: str = field(default="", compare=False)


# --------------------------------------------------------------------------- pure parsing


def is_libllvm_name(filename: str) -> bool:
    """Whether a file name (or path) names a whole shared libLLVM, not an LLVM component."""
    return bool(_LIB_NAME.match(os.path.basename(filename)))


def parse_llvm_major(filename: str) -> int | None:
    """Major LLVM version carried by a library file name, or None when the name has none.

    >>> parse_llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-17.so.1"), parse_llvm_major("libLLVM.so.19.1")
    (17, 19)
    >>> parse_llvm_major("libLLVM.so") is None
    True
    """
    name = os.path.basename(filename)
    for pattern in _MAJOR_PATTERNS:
        m = pattern.match(name)
        if m:
            return int(m.group(1))
    return None


def parse_ldconfig(text: str, machine: str | None = None) -> list[str]:
    """Paths of shared libLLVM libraries in ``ldconfig -p`` output, in the order listed.

    Lines look like ``\\tlibLLVM-15.so.1 (libc6,x86-64) => /lib/x86_64-linux-gnu/libLLVM-15.so.1``.
    Component libraries (``libLLVMSPIRVLib.so``) are skipped. When ``machine`` (a
    ``platform.machine()`` value such as ``"x86_64"``) has a known ldconfig tag, entries for other
    architectures (e.g. 32-bit ``(libc6)`` ones) are skipped too; ``None`` keeps every entry.
    """
    tag = _LDCONFIG_TAGS.get(machine or "")
    paths = []
    for line in text.splitlines():
        if "=>" not in line:
            continue
        left, path = (s.strip() for s in line.split("=>", 1))
        name, _, flags = left.partition(" ")
        if not is_libllvm_name(name) or not path:
            continue
        if tag is not None and tag not in flags:
            continue
        paths.append(path)
    return paths


def pick_newest(libs: Iterable[LibLLVM], min_major: int = MIN_LLVM) -> LibLLVM | None:
    """The library of highest major version >= ``min_major`` (the first on a tie), or None."""
    best: LibLLVM | None = None
    for lib in libs:
        if lib.major >= min_major and (best is None or lib.major > best.major):
            best = lib
    return best


# --------------------------------------------------------------------------- probing the disk


@functools.lru_cache(maxsize=64)
def _probe_cached(realpath: str, mtime_ns: int, size: int) -> tuple[int | None, str]:
    """Ask a library its version in a child process (cached per file identity)."""
    del mtime_ns, size  # part of the cache key only
    try:
        r = subprocess.run([sys.executable, "-I", "-c", _PROBE, realpath], capture_output=True,
                           text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as e:
        return None, f"could not be probed ({e})"
    out = r.stdout.strip()
    if r.returncode == 0 and re.fullmatch(r"\d+\.\d+\.\d+", out):
        return int(out.split(".")[0]), f"is LLVM {out}"
    if r.returncode < 0:
        return None, f"crashed the process that loaded it (signal {-r.returncode})"
    return None, out or f"could not be loaded (exit {r.returncode}): {r.stderr.strip()[-300:]}"


def probe_library(path: str) -> tuple[int | None, str]:
    """Load ``path`` in a subprocess and call ``LLVMGetVersion``; returns (major or None, detail).

    ``None`` means the file cannot be loaded or lacks ``LLVMGetVersion`` (LLVM < 16); the detail
    string says which. The caller's process never loads the library, so it cannot be crashed.
    """
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except OSError as e:
        return None, f"cannot be read ({e.strerror})"
    return _probe_cached(real, st.st_mtime_ns, st.st_size)


def library_version(path: str) -> int | None:
    """Major version of a libLLVM file: from its name, else the name it links to, else by asking it."""
    major = parse_llvm_major(path)
    if major is None:
        major = parse_llvm_major(os.path.realpath(path))
    if major is None:
        major, _ = probe_library(path)
    return major


def _ldconfig_output() -> str:
    """``ldconfig -p`` output, or "" where there is no ldconfig (macOS) or it fails."""
    for exe in ("ldconfig", "/sbin/ldconfig", "/usr/sbin/ldconfig"):
        try:
            r = subprocess.run([exe, "-p"], capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if r.returncode == 0:
            return r.stdout
    return ""


def candidate_paths() -> list[tuple[str, str]]:
    """Existing libLLVM files as (path, source) in search order, one per real file."""
    found = [(p, "ldconfig") for p in parse_ldconfig(_ldconfig_output(), platform.machine())]
    for folder in SEARCH_DIRS:
        for d in sorted(glob.glob(folder)):
            for pattern in LIB_PATTERNS:
                found += [(p, "search") for p in sorted(glob.glob(os.path.join(d, pattern)))]
    seen: set[str] = set()
    unique = []
    for path, source in found:
        real = os.path.realpath(path)
        if real not in seen and os.path.isfile(real):
            seen.add(real)
            unique.append((path, source))
    return unique


def _check_env_library(path: str, min_major: int) -> LibLLVM:
    """Validate an explicitly configured library (``$DRJIT_LIBLLVM_PATH``)."""
    if not os.path.isfile(path):
        raise BackendError(f"{ENV_LLVM}={path} is not an existing file (give the full path of a "
                           f"libLLVM >= {min_major}); {FIX}")
    major = parse_llvm_major(path) or parse_llvm_major(os.path.realpath(path))
    detail = f"is libLLVM {major}" if major is not None else ""
    if major is None:
        major, detail = probe_library(path)
    if major is None or major < min_major:
        raise BackendError(f"{ENV_LLVM}={path} {detail or 'is too old'}, but Dr.Jit's LLVM backend "
                           f"needs libLLVM >= {min_major} (older versions abort the process); {FIX}")
    return LibLLVM(path, major, ENV_LLVM)


def find_libllvm(min_major: int = MIN_LLVM) -> LibLLVM | None:
    """Find a shared libLLVM >= ``min_major`` for Dr.Jit, or return None when there is none.

    Order (module docstring): ``$DRJIT_LIBLLVM_PATH`` if set -- validated and returned, or
    :class:`BackendError` if it is missing or older than ``min_major`` -- else the highest version
    among ``ldconfig -p`` and the :data:`SEARCH_DIRS` globs. Libraries whose names carry no version
    are asked in a subprocess.
    """
    env = os.environ.get(ENV_LLVM)
    if env:
        return _check_env_library(env, min_major)
    libs = []
    for path, source in candidate_paths():
        major = library_version(path)
        if major is not None:
            libs.append(LibLLVM(path, major, source))
    return pick_newest(libs, min_major)


# --------------------------------------------------------------------------- configuring drjit


def _loaded_llvm() -> tuple[int, str]:
    """(major, path) of the libLLVM an already imported drjit loaded; major -1 if none."""
    import drjit as dr

    version = getattr(getattr(dr, "detail", None), "llvm_version", None)
    major = int(version()[0]) if version is not None else -1
    path = ""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            path = next((fields[-1] for fields in map(str.split, f)
                         if len(fields) >= 6 and is_libllvm_name(fields[-1])), "")
    except OSError:
        pass
    if version is None and path:  # older drjit without llvm_version(): go by the file name
        major = library_version(path) or -1
    return major, path


def configure_llvm() -> LibLLVM:
    """Make Dr.Jit use a libLLVM >= 16; call before drjit or mitsuba is imported.

    Sets ``os.environ["DRJIT_LIBLLVM_PATH"]`` to :func:`find_libllvm`'s choice unless it already
    names a valid library, and returns the library. Idempotent.

    If drjit is already imported, its choice is final (Dr.Jit reads the variable at import): the
    library it loaded is returned when it is >= 16, else :class:`BackendError` says to call this
    (or :func:`import_mitsuba`) before importing drjit/mitsuba.

    Raises:
        BackendError: no libLLVM >= 16 exists (the message says how to install one), or
            ``$DRJIT_LIBLLVM_PATH`` names a missing/old library, or drjit already loaded an old one.
    """
    if "drjit" in sys.modules:
        major, path = _loaded_llvm()
        if major >= MIN_LLVM:
            return LibLLVM(path or os.environ.get(ENV_LLVM, ""), major, "drjit")
        try:
            good = find_libllvm()
        except BackendError:
            good = None
        hint = f"e.g. {ENV_LLVM}={good.path} " if good else ""
        loaded = f"libLLVM {major}" if major > 0 else "no usable libLLVM"
        raise BackendError(
            f"drjit was imported before mitsvbrdf.backend.configure_llvm() and loaded {loaded}; "
            f"Dr.Jit's LLVM backend needs libLLVM >= {MIN_LLVM} (older versions abort the process). "
            f"Call mitsvbrdf.backend.configure_llvm() or import_mitsuba() before importing "
            f"drjit/mitsuba, or set {hint}before starting Python"
            + ("" if good else f"; {FIX}"))
    lib = find_libllvm()
    if lib is None:
        raise BackendError(f"no libLLVM >= {MIN_LLVM} found for Dr.Jit's LLVM backend "
                           f"(searched {ENV_LLVM}, ldconfig -p, {', '.join(SEARCH_DIRS)}); {FIX}")
    os.environ[ENV_LLVM] = lib.path
    return lib


# --------------------------------------------------------------------------- variants


def cuda_available() -> bool:
    """Whether torch sees a usable CUDA device; False when torch is missing. Never raises."""
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - any failure means "no CUDA" here
        return False


def choose_variant(prefer: str | None = None) -> str:
    """The Mitsuba variant to use.

    ``prefer`` wins, then ``$MITSVBRDF_VARIANT``, then ``cuda_ad_rgb`` when :func:`cuda_available`,
    else ``llvm_ad_rgb``. An explicit choice must be one of :data:`VARIANTS` (BackendError if not).
    """
    chosen, origin = (prefer, "variant") if prefer else (os.environ.get(ENV_VARIANT), ENV_VARIANT)
    if chosen:
        if chosen not in VARIANTS:
            raise BackendError(f"unknown Mitsuba variant {chosen!r} (from {origin}); choose one of "
                               f"{', '.join(VARIANTS)}")
        return chosen
    return "cuda_ad_rgb" if cuda_available() else "llvm_ad_rgb"


def import_mitsuba(variant: str | None = None) -> ModuleType:
    """Import Mitsuba with a safe backend, set ``variant`` and return the ``mitsuba`` module.

    ``variant`` is resolved by :func:`choose_variant`. For ``llvm_*`` variants
    :func:`configure_llvm` runs first (and its BackendError propagates); for others it runs on a
    best-effort basis. After the variant is set, an LLVM variant is checked once more against the
    libLLVM Dr.Jit actually loaded. Idempotent: calling again with the same variant is cheap;
    another variant switches Mitsuba to it.

    Raises:
        BackendError: no suitable libLLVM, mitsuba not installed, or the variant unusable here
            (e.g. ``cuda_ad_rgb`` without an NVIDIA GPU/driver).
    """
    variant = choose_variant(variant)
    llvm = variant.startswith("llvm")
    if llvm:
        configure_llvm()
    else:
        try:
            configure_llvm()  # harmless when it works; CUDA/scalar variants do not need LLVM
        except BackendError:
            pass
    try:
        import mitsuba as mi
    except ImportError as e:
        raise BackendError(f"mitsuba cannot be imported ({e}); run scripts/setup.sh") from e
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except (ImportError, AttributeError, ValueError, RuntimeError) as e:
            hint = (" (needs an NVIDIA GPU and driver; use llvm_ad_rgb on the CPU)"
                    if variant.startswith("cuda") else "")
            raise BackendError(f"Mitsuba variant {variant!r} is not usable here{hint}: "
                               f"{str(e).strip().rstrip('.')}. "
                               f"Choose another with {ENV_VARIANT}=... or import_mitsuba(variant=...)"
                               ) from e
    if llvm:
        major, _ = _loaded_llvm()
        if major < MIN_LLVM:  # pragma: no cover - configure_llvm() prevents this
            raise BackendError(f"Dr.Jit loaded libLLVM {major}, but needs >= {MIN_LLVM}; {FIX}")
    return mi


def torch_device_for(variant: str) -> "torch.device":
    """The torch device whose tensors the Mitsuba ``variant`` can wrap without copies.

    ``cuda`` for ``cuda_*`` variants, else ``cpu``.
    """
    import torch

    return torch.device("cuda" if variant.startswith("cuda") else "cpu")


# --------------------------------------------------------------------------- command line


def _version_of(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def main(argv: list[str] | None = None) -> int:
    """``python -m mitsvbrdf.backend [--check-llvm]``; returns the exit status."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m mitsvbrdf.backend",
                                     description="Report the Mitsuba/Dr.Jit backend this machine gets.")
    parser.add_argument("--check-llvm", action="store_true",
                        help=f"print the path of a libLLVM >= {MIN_LLVM} and exit 0, or exit 1 if none")
    args = parser.parse_args(argv)

    try:
        lib, llvm_error = find_libllvm(), ""
    except BackendError as e:
        lib, llvm_error = None, str(e)
    if args.check_llvm:
        if lib is None:
            print(llvm_error or f"no libLLVM >= {MIN_LLVM} found; {FIX}", file=sys.stderr)
            return 1
        print(lib.path)
        return 0

    try:
        variant = choose_variant()
    except BackendError as e:
        variant = f"invalid ({e})"
    print(f"variant: {variant}")
    if lib is not None:
        print(f"libLLVM: {lib.path} (LLVM {lib.major}, from {lib.source})")
    else:
        print(f"libLLVM: none usable: {llvm_error or f'no libLLVM >= {MIN_LLVM} found; {FIX}'}")
    print(f"CUDA: {'yes' if cuda_available() else 'no'}")
    print(f"mitsuba {_version_of('mitsuba')}, drjit {_version_of('drjit')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
