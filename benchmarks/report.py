"""Shared output of the benchmark scripts: a markdown table and a CSV of the same rows."""

from __future__ import annotations

import csv
import os
from pathlib import Path

#: The 4 sample materials (Deschaintre-format strips): $MITSVBRDF_SAMPLES, else the checkout's
#: sibling shared/data/svbrdf_samples (as tests/conftest.py finds them).
SAMPLES = Path(os.environ.get("MITSVBRDF_SAMPLES",
                              Path(__file__).resolve().parents[2] / "shared" / "data" / "svbrdf_samples"))


def write_report(out_dir: Path, stem: str, title: str, script: str, text: str, rows: list[dict]) -> None:
    """Write ``<stem>.md`` (title, provenance line, ``text``) and ``<stem>.csv`` (``rows``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{stem}.md").write_text(f"# {title}\n\nWritten by `benchmarks/{script}`.\n\n{text}")
    write_csv(out_dir / f"{stem}.csv", rows)


def machine_load() -> str:
    """A sentence for a timing table: the 1-minute load average against the core count. Timings
    taken beside other work (a training run, tests) are inflated, and by different factors for
    different methods; the sentence lets a reader tell such a run from a quiet one."""
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    busy = " (busy: other work shared the cores, so the times are inflated)" if load > 0.5 * cores else ""
    return f"Load average over the last minute when the timings ended: {load:.2f} on {cores} cores{busy}."


def write_csv(path: Path, rows: list[dict]) -> None:
    """``rows`` (dicts with the same keys) as a CSV file with a header line."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
