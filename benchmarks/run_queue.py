"""Training runs of a study, trained several at once: shared by the benchmark scripts that train
(table3.py, gsc_sample_efficiency.py).

A :class:`Run` is one ``mitsvbrdf train`` invocation (config, ``--set`` overrides, output folder)
and the run whose export it starts from, if any. :func:`train_all` trains every run that has no
``networks.pt`` yet, up to ``jobs`` at once, each after its parent; a run with a checkpoint
resumes from it. Runs side by side share the cores: each gets ``cores // jobs`` OpenMP threads,
because OpenMP threads spin while they wait, and two 2-thread CPU runs side by side on 2 cores
slowed each other ten-fold. A run that fails stops the others (they checkpoint; a rerun resumes
them).
"""

from __future__ import annotations

import os
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Run:
    """One training run of a study: its config, overrides, output folder and the run it starts from."""

    name: str
    config: Path
    out: Path
    parent: str | None = None
    overrides: list[str] = field(default_factory=list)


def train_all(runs: dict[str, Run], python: str, jobs: int = 1, tag: str = "runs") -> None:
    """Train every unfinished run of ``runs`` (by key; ``parent`` names a key), up to ``jobs`` at
    once, each after the run it starts from. With more than one job each run's output goes to
    ``<out>/train.log``. ``tag`` prefixes the progress lines."""
    done = {k for k, r in runs.items() if (r.out / "networks.pt").exists()}
    for k in sorted(done):
        print(f"[{tag}] {k}: done, kept")
    todo = [k for k in runs if k not in done]
    active: dict[str, tuple[subprocess.Popen, float]] = {}
    while todo or active:
        for k in list(todo):
            if len(active) >= jobs:
                break
            r = runs[k]
            if r.parent and r.parent not in done:
                continue
            cmd = [python, "-m", "mitsvbrdf", "train", str(r.config), "--quiet"]
            cmd += [a for o in r.overrides for a in ("--set", o)]
            if (r.out / "checkpoint.pt").exists():
                cmd.append("--resume")
            print(f"[{tag}] start {k}: {' '.join(cmd[1:])}", flush=True)
            log, env = None, None
            if jobs > 1:
                r.out.mkdir(parents=True, exist_ok=True)
                log = open(r.out / "train.log", "a")
                env = {**os.environ, "OMP_NUM_THREADS": str(max(1, (os.cpu_count() or 1) // jobs))}
            active[k] = (subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT if log else None,
                                          env=env), time.perf_counter())
            todo.remove(k)
        if not active:
            raise RuntimeError(f"runs {todo} wait for runs that are neither done nor planned")
        time.sleep(1)
        for k, (proc, t0) in list(active.items()):
            if proc.poll() is None:
                continue
            del active[k]
            if proc.returncode != 0:
                for other, _ in active.values():
                    other.terminate()  # they checkpoint; a rerun resumes them
                raise RuntimeError(f"run {k} failed (exit {proc.returncode}); see its output"
                                   + (f" in {runs[k].out / 'train.log'}" if jobs > 1 else ""))
            done.add(k)
            print(f"[{tag}] {k}: {time.perf_counter() - t0:.0f} s", flush=True)
