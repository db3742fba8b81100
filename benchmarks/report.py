"""Shared output of the benchmark scripts: a markdown table and a CSV of the same rows."""

from __future__ import annotations

import csv
import os
import statistics
import time
from pathlib import Path

import mitsvbrdf as ms
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.evaluation import load_materials

#: The 4 sample materials (Deschaintre-format strips): $MITSVBRDF_SAMPLES, else the checkout's
#: sibling shared/data/svbrdf_samples (as tests/conftest.py finds them).
SAMPLES = Path(os.environ.get("MITSVBRDF_SAMPLES",
                              Path(__file__).resolve().parents[2] / "shared" / "data" / "svbrdf_samples"))


def goal_sets(size: int, n: int) -> dict[str, list[ms.SVBRDF]]:
    """The material sets the issue's goals name, at ``size`` px: the demo's bundled material, the
    sample materials (when :data:`SAMPLES` is there) and ``n`` held-out procedural materials
    (``evaluate``'s seeds)."""
    sets = {"demo material": [ms.SVBRDF.load(DEFAULT_MATERIAL).resized(size)]}
    if SAMPLES.is_dir():
        sets["4 samples"] = load_materials(str(SAMPLES), size, 0)
    sets[f"{n} procedural"] = load_materials("procedural", size, n)
    return sets


def write_report(out_dir: Path, stem: str, title: str, script: str, text: str, rows: list[dict]) -> None:
    """Write ``<stem>.md`` (title, provenance line, ``text``) and ``<stem>.csv`` (``rows``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{stem}.md").write_text(f"# {title}\n\nWritten by `benchmarks/{script}`.\n\n{text}")
    write_csv(out_dir / f"{stem}.csv", rows)


class OtherLoad:
    """How many cores other processes kept busy since this object was made (Linux: /proc/stat's
    busy time less this process's own CPU time, over the wall time). Timings taken beside other
    work (a training run, tests) are inflated, and by different factors for different methods;
    the sentence lets a reader tell such a run from a quiet one. (The load average is no measure
    here: it counts the benchmark's own threads.)"""

    def __init__(self):
        self.start = self._sample()

    @staticmethod
    def _sample() -> tuple[float, float, float] | None:
        try:
            with open("/proc/stat") as f:
                ticks = [int(v) for v in f.readline().split()[1:9]]
        except (OSError, ValueError):
            return None
        own = os.times()
        busy = (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")  # all but idle and iowait
        return time.monotonic(), busy, own.user + own.system

    def sentence(self) -> str:
        end = self._sample()
        if self.start is None or end is None:
            return "Other work on the machine meanwhile: not measured (no /proc/stat)."
        wall = max(end[0] - self.start[0], 1e-9)
        other = max(0.0, (end[1] - self.start[1]) - (end[2] - self.start[2])) / wall
        cores = os.cpu_count() or 1
        busy = " (busy: other work shared the cores, so the times are inflated)" if other > 0.25 * cores else ""
        return f"Other processes kept {other:.2f} of {cores} cores busy on average while this ran{busy}."


def write_csv(path: Path, rows: list[dict]) -> None:
    """``rows`` (dicts with the same keys) as a CSV file with a header line."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def interleaved_seconds(fns: dict, repeats: int = 5, *, before=None, settle: bool = False) -> dict:
    """Median wall time of ``repeats`` calls of each of ``fns`` (name -> callable), in rounds of
    one call each (after one untimed call each), so that every one sees the same drift of the
    process and the machine; ``before()`` runs untimed ahead of every call. With ``settle``, each
    timed call follows an untimed call of the same function (before ``before()``), so that what the
    previous function left behind (e.g. a scene to load again) is not timed."""
    for fn in fns.values():
        fn()
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            if settle:
                fn()
            if before is not None:
                before()
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(t) for name, t in times.items()}


def median_seconds(fn, repeats: int = 5, *, warmup: bool = True, before=None) -> float:
    """Median wall time of ``repeats`` calls of ``fn`` (after one untimed call with ``warmup``);
    ``before()``, when given, runs untimed ahead of every call (e.g. clearing a cache)."""
    if warmup:
        fn()
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)
