"""benchmarks/paired_metrics.py: two evaluations' metrics.csv compared material by material."""

import csv

import pytest

from mitsvbrdf.evaluation import MAP_COLUMNS

from conftest import benchmark_module

study = benchmark_module("paired_metrics")


def write_metrics(path, scores: dict[str, float], method: str = "adaptive"):
    """A metrics.csv with every map of material m scoring scores[m]."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["method", "material", *MAP_COLUMNS, "ssim"])
        w.writeheader()
        for m, s in scores.items():
            w.writerow({"method": method, "material": m, **dict.fromkeys(MAP_COLUMNS, s), "ssim": 0.9})
    return path


def paired_row(text: str, name: str) -> list[str]:
    """The cells of the paired table's last row, which is ``name``'s."""
    row = text.splitlines()[-1]
    assert row.startswith(f"| {name} |"), text
    return [c.strip() for c in row.strip("|").split("|")]


def test_materials_are_paired_by_name_whatever_their_order(tmp_path):
    a = write_metrics(tmp_path / "a.csv", {"m0": 0.10, "m1": 0.20, "m2": 0.30})
    b = write_metrics(tmp_path / "b.csv", {"m2": 0.27, "m0": 0.08, "m1": 0.19})  # -0.03, -0.02, -0.01
    text = study.compare(study.read_rows(a, "adaptive", "a"), study.read_rows(b, "adaptive", "b"), ("a", "b"))
    row = paired_row(text, "b")
    # mean -0.02; standard error = std(ddof=1) / sqrt(3) = 0.01 / sqrt(3) = 0.0058; a lower on none
    assert row[1:6] == ["-0.0200 +- 0.0058"] * 5 and row[6] == "0/3"


def test_materials_scored_by_one_file_only_are_left_out_and_counted(tmp_path):
    a = write_metrics(tmp_path / "a.csv", {"m0": 0.10, "m1": 0.20, "extra": 5.0})
    b = write_metrics(tmp_path / "b.csv", {"m0": 0.12, "m1": 0.22})
    text = study.compare(study.read_rows(a, "adaptive", "a"), study.read_rows(b, "adaptive", "b"), ("a", "b"))
    assert "over the 2 materials both evaluations scored (1 scored by one only, left out)" in text
    assert "| a | 0.1500 |" in text  # the mean without the unmatched material's 5.0
    assert paired_row(text, "b")[6] == "2/2"


def test_files_without_a_material_in_common_are_refused(tmp_path):
    a = write_metrics(tmp_path / "a.csv", {"m0": 0.1})
    b = write_metrics(tmp_path / "b.csv", {"m1": 0.1})
    with pytest.raises(ValueError, match="no material in common"):
        study.compare(study.read_rows(a, "adaptive", "a"), study.read_rows(b, "adaptive", "b"), ("a", "b"))


def test_a_file_without_the_method_is_refused_naming_it(tmp_path):
    a = write_metrics(tmp_path / "a.csv", {"m0": 0.1}, method="fixed-monograd")
    with pytest.raises(ValueError, match="no rows of method 'adaptive'"):
        study.read_rows(a, "adaptive", "a")
