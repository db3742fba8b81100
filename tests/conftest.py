"""Shared fixtures: the default rig and small materials (tests run at 8-32 px)."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest
import torch

import mitsvbrdf as ms


#: The 4 sample materials (Deschaintre-format strips) some tests read: MITSVBRDF_SAMPLES, else the
#: checkout's sibling shared/data/svbrdf_samples. Absent on a clean clone: those tests skip, saying so.
SAMPLES = Path(os.environ.get("MITSVBRDF_SAMPLES", Path(__file__).resolve().parents[2] / "shared" / "data"
                              / "svbrdf_samples"))
needs_samples = pytest.mark.skipif(
    not (SAMPLES / "0_svbrdf.png").is_file(),
    reason=f"sample materials not found in {SAMPLES}: set MITSVBRDF_SAMPLES to the folder of *_svbrdf.png strips")


def benchmark_module(name: str):
    """The script benchmarks/<name>.py as a module (its sibling modules importable while it loads)."""
    benchmarks = Path(__file__).resolve().parents[1] / "benchmarks"
    sys.path.insert(0, str(benchmarks))  # the scripts import their siblings (report.py, ...)
    try:
        spec = importlib.util.spec_from_file_location(name, benchmarks / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # a dataclass looks its module up there
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(benchmarks))
        sys.modules.pop(name, None)
    return module


@pytest.fixture(scope="module")
def one_torch_thread():
    """One intra-op thread for a module: the procedural generator is many small ops, and extra
    threads only wait for each other on a busy 2-core machine."""
    prev = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(prev)


@pytest.fixture(scope="session")
def rig() -> ms.Rig:
    return ms.Rig.from_scene()


def flat_material(size: int = 16, *, diffuse=0.5, specular=0.04, roughness=0.5, normal=(0.0, 0.0, 1.0)):
    """A homogeneous SVBRDF (B = 1) on a size x size grid."""
    return ms.SVBRDF.constant(normal=normal, diffuse=diffuse, roughness=roughness, specular=specular, size=size)


def textured_material(size: int = 16, seed: int = 0, roughness=(0.05, 0.8)):
    """A random but smooth-ish SVBRDF with a bumpy normal map, for gradient and batch tests."""
    g = torch.Generator().manual_seed(seed)
    n = torch.randn(1, 3, size, size, generator=g) * 0.25
    n[:, 2] = 1.0
    n = n / n.norm(dim=1, keepdim=True)
    lo, hi = roughness
    return ms.SVBRDF(normal=n, diffuse=torch.rand(1, 3, size, size, generator=g),
                     roughness=lo + (hi - lo) * torch.rand(1, 1, size, size, generator=g),
                     specular=0.02 + 0.5 * torch.rand(1, 3, size, size, generator=g))


def jit_kernels_of(fn) -> list[dict]:
    """Dr.Jit's records of the JIT kernels that ``fn()`` launched (each with ``cache_hit``): a
    kernel it had to compile has ``cache_hit`` false."""
    import drjit as dr

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    try:
        fn()
        return [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
