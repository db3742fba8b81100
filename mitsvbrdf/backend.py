"""Choose and import the Mitsuba/Dr.Jit backend safely.

Why this module exists: Dr.Jit's LLVM backend needs a shared libLLVM >= 16. Debian 12 often has
libLLVM-15 as well, and if Dr.Jit picks it the whole process *aborts* inside LLVM ("Cannot select
... fminimum") with no Python exception to catch. So before drjit is imported we find a suitable
library ourselves and point ``DRJIT_LIBLLVM_PATH`` at it, and we refuse (with a clear
:class:`BackendError`) rather than let Dr.Jit fall back to an old one.

Order of precedence:

* libLLVM: ``$DRJIT_LIBLLVM_PATH`` if set (it must exist and be >= 16, else BackendError), then
  the libraries ``ldconfig -p`` lists, then common install folders; the highest version wins.
  Versions come from file names (``libLLVM-17.so.1``, ``libLLVM.so.19.1``); an unversioned
  ``libLLVM.so`` is asked for ``LLVMGetVersion`` in a subprocess (so a bad library cannot crash us).
* variant: the ``variant`` argument, then ``$MITSVBRDF_VARIANT``, then ``cuda_ad_rgb`` when CUDA
  is usable, else ``llvm_ad_rgb``.

``python -m mitsvbrdf.backend`` prints a report; ``--check-llvm`` exits 0 with the library's path
when a suitable libLLVM exists and 1 otherwise (used by ``scripts/setup.sh``).
"""

from __future__ import annotations

import glob
import os
import re
import subprocess
import sys
from dataclasses import dataclass

from .errors import BackendError

MIN_LLVM = 16
VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb", "cuda_rgb", "llvm_rgb")
_SEARCH_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib/llvm-*/lib",
                "/usr/local/lib", "/usr/lib64", "/usr/lib", "/opt/homebrew/opt/llvm/lib")
_FIX = ("install Debian's libllvm19 (apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH to a "
        f"libLLVM >= {MIN_LLVM}")


@dataclass(frozen=True)
class LibLLVM:
    """A shared libLLVM on disk and its major version."""

    path: str
    major: int


def parse_llvm_major(filename: str) -> int | None:
    """Major version from a library file name, or None when the name carries none."""
    name = os.path.basename(filename)
    m = re.match(r"libLLVM-(\d+)", name) or re.match(r"libLLVM\.so\.(\d+)", name) or \
        re.match(r"libLLVM\.(\d+)(?:\.\d+)*\.dylib", name)
    return int(m.group(1)) if m else None


def parse_ldconfig(text: str) -> list[str]:
    """Paths of libLLVM libraries in ``ldconfig -p`` output."""
    return [line.split("=>", 1)[1].strip() for line in text.splitlines()
            if "libLLVM" in line and "=>" in line]


def _query_version(path: str) -> int | None:
    """Ask the library itself (LLVMGetVersion, LLVM >= 16) in a subprocess; None if too old/unloadable."""
    code = ("import ctypes,sys;l=ctypes.CDLL(sys.argv[1]);f=getattr(l,'LLVMGetVersion',None)\n"
            "if f is None: sys.exit(3)\n"
            "a,b,c=(ctypes.c_uint(),ctypes.c_uint(),ctypes.c_uint());f(ctypes.byref(a),ctypes.byref(b),"
            "ctypes.byref(c));print(a.value)")
    try:
        out = subprocess.run([sys.executable, "-c", code, path], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return int(out.stdout.strip()) if out.returncode == 0 and out.stdout.strip().isdigit() else None


def library_version(path: str) -> int | None:
    """Major version of a libLLVM file: from its name, else by asking it."""
    major = parse_llvm_major(path)
    return major if major is not None else _query_version(path)


def _candidates() -> list[str]:
    paths: list[str] = []
    try:
        out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=20)
        paths += parse_ldconfig(out.stdout)
    except (OSError, subprocess.TimeoutExpired):
        pass
    for d in _SEARCH_DIRS:
        for pattern in ("libLLVM-*.so*", "libLLVM.so*", "libLLVM*.dylib"):
            paths += sorted(glob.glob(os.path.join(d, pattern)))
    seen, unique = set(), []
    for p in paths:
        real = os.path.realpath(p)
        if os.path.isfile(p) and real not in seen:
            seen.add(real)
            unique.append(p)
    return unique


def pick_newest(libs: list[LibLLVM], min_major: int = MIN_LLVM) -> LibLLVM | None:
    """The highest-version library at or above ``min_major``."""
    ok = [lib for lib in libs if lib.major >= min_major]
    return max(ok, key=lambda lib: lib.major) if ok else None


def find_libllvm(min_major: int = MIN_LLVM) -> LibLLVM | None:
    """A libLLVM >= ``min_major`` (see the module docstring for the search order), or None."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        if not os.path.isfile(env):
            raise BackendError(f"DRJIT_LIBLLVM_PATH={env} does not exist; {_FIX}")
        major = library_version(env)
        if major is None or major < min_major:
            raise BackendError(f"DRJIT_LIBLLVM_PATH={env} is libLLVM {major or '< 16'}, but Dr.Jit needs "
                               f">= {min_major} (older versions abort the process); {_FIX}")
        return LibLLVM(env, major)
    named, unnamed = [], []
    for path in _candidates():
        major = parse_llvm_major(path)
        (named if major is not None else unnamed).append((path, major))
    libs = [LibLLVM(p, m) for p, m in named]
    best = pick_newest(libs, min_major)
    if best is None:
        libs += [LibLLVM(p, m) for p, m in ((p, _query_version(p)) for p, _ in unnamed) if m is not None]
        best = pick_newest(libs, min_major)
    return best


def configure_llvm() -> LibLLVM:
    """Point ``DRJIT_LIBLLVM_PATH`` at a libLLVM >= 16 before drjit is imported."""
    lib = find_libllvm()
    if lib is None:
        raise BackendError(f"no libLLVM >= {MIN_LLVM} found for Dr.Jit's LLVM backend; {_FIX}")
    if "drjit" in sys.modules and os.environ.get("DRJIT_LIBLLVM_PATH") != lib.path:
        raise BackendError("drjit was imported before mitsvbrdf.backend could choose libLLVM; call "
                           "import_mitsuba() (or configure_llvm()) before importing drjit/mitsuba, "
                           f"or set DRJIT_LIBLLVM_PATH={lib.path}")
    os.environ["DRJIT_LIBLLVM_PATH"] = lib.path
    return lib


def cuda_available() -> bool:
    """Whether a CUDA device is usable (via torch); never raises."""
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:
        return False


def choose_variant(prefer: str | None = None) -> str:
    """The Mitsuba variant to use: ``prefer``, ``$MITSVBRDF_VARIANT``, CUDA if usable, else LLVM."""
    v = prefer or os.environ.get("MITSVBRDF_VARIANT")
    if v:
        if v not in VARIANTS:
            raise BackendError(f"unknown Mitsuba variant {v!r}; choose one of {', '.join(VARIANTS)}")
        return v
    return "cuda_ad_rgb" if cuda_available() else "llvm_ad_rgb"


def import_mitsuba(variant: str | None = None):
    """Configure libLLVM if needed, import mitsuba, set the variant and return the module."""
    variant = choose_variant(variant)
    if variant.startswith("llvm"):
        configure_llvm()
    try:
        import mitsuba as mi
    except ImportError as e:
        raise BackendError(f"mitsuba cannot be imported ({e}); run scripts/setup.sh") from e
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except (ImportError, AttributeError, ValueError) as e:
            raise BackendError(f"Mitsuba variant {variant!r} is not usable here ({e})") from e
    return mi


def torch_device_for(variant: str):
    """The torch device whose tensors Dr.Jit's ``variant`` can wrap without copies."""
    import torch

    return torch.device("cuda" if variant.startswith("cuda") else "cpu")


def _main(argv: list[str]) -> int:
    if "--check-llvm" in argv:
        try:
            lib = find_libllvm()
        except BackendError as e:
            print(e, file=sys.stderr)
            return 1
        if lib is None:
            print(f"no libLLVM >= {MIN_LLVM} found", file=sys.stderr)
            return 1
        print(lib.path)
        return 0
    try:
        lib = find_libllvm()
    except BackendError as e:
        lib = None
        print(f"libLLVM: {e}")
    print(f"variant: {choose_variant()}")
    print(f"libLLVM: {lib.path} (LLVM {lib.major})" if lib else f"libLLVM: none >= {MIN_LLVM} ({_FIX})")
    print(f"CUDA: {'yes' if cuda_available() else 'no'}")
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
