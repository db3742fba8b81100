"""The renderer-timing benchmarks run with torch's OpenMP threads sleeping when idle.

Import this module before torch (libgomp reads its settings once, when torch loads it). After
each parallel torch operation, libgomp's idle threads spin for a while (``GOMP_SPINCOUNT``,
300000 iterations by default) before they sleep; a Dr.Jit render that follows shares the cores
with them. How much of a core they take depends on each process's timing: the same render's
median differs by up to half between processes (``GOMP_SPINCOUNT=300000 python
benchmarks/cv_cost.py --name libgomp-default``, run twice, against docs/benchmarks/cv_cost.md).
With ``OMP_WAIT_POLICY=PASSIVE`` they sleep at once, and the timings compare the renderers
themselves. Training keeps libgomp's default: its networks are slower with sleeping threads
(docs/benchmarks/training_speed_cpu_scratch-small_passive-openmp.md against
training_speed_cpu_scratch-small.md).

Set ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT`` yourself to time otherwise; this module then
changes nothing (``GOMP_SPINCOUNT=300000`` is libgomp's default behaviour).
"""

from __future__ import annotations

import os
import sys

if "torch" in sys.modules:  # too late: libgomp has read its settings
    raise ImportError("benchmarks/openmp_policy.py must be imported before torch")
if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"


def sentence() -> str:
    """How torch's idle OpenMP threads waited in this run, for a report."""
    if os.environ.get("OMP_WAIT_POLICY", "").upper() == "PASSIVE":
        return "torch's idle OpenMP threads slept (OMP_WAIT_POLICY=PASSIVE; benchmarks/openmp_policy.py)."
    settings = ", ".join(f"{k}={os.environ[k]}" for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT") if k in os.environ)
    return f"torch's idle OpenMP threads spun before sleeping ({settings}; benchmarks/openmp_policy.py)."
