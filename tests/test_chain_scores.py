"""benchmarks/chain_scores.py: one table row per scored chain, from its committed record and summaries."""

import csv
import json

import pytest

from conftest import benchmark_module

study = benchmark_module("chain_scores")


def make_run(folder, *, stages: dict[str, int], budget_s: float = 9000.0, demo: tuple | None = (0.03, 0.04),
             summaries: dict[str, dict[str, tuple]] | None = None):
    """A run folder as the evaluation notes lay it out; summaries: set folder -> {method: (avg, normal)}."""
    (folder / "records").mkdir(parents=True)
    (folder / "records" / "chain.json").write_text(json.dumps({
        "chain": "train/chains/x.toml", "time_budget_s": budget_s,
        "stages": [{"stage": s, "steps": n} for s, n in stages.items()]}))
    if demo is not None:
        (folder / "demo-x.json").write_text(json.dumps({"metrics": {"rmse_average": demo[0], "rmse_normal": demo[1]}}))
    for sub, methods in (summaries or {}).items():
        (folder / sub).mkdir()
        with open(folder / sub / "summary.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["method", "materials", "rmse_normal", "rmse_average"])
            w.writeheader()
            for m, (avg, normal) in methods.items():
                w.writerow({"method": m, "materials": 32, "rmse_normal": normal, "rmse_average": avg})
    return folder


def row(text: str, label: str) -> list[str]:
    line = next(l for l in text.splitlines() if l.startswith(f"| {label} |"))
    return [c.strip() for c in line.strip("|").split("|")]


def test_a_row_holds_the_budget_the_initializer_steps_and_the_gsc_steps_of_stage2_and_finetune(tmp_path):
    run = make_run(tmp_path / "r", stages={"init": 100, "stage1": 20, "stage2": 300, "finetune": 400})
    cells = row(study.table([(run, None)]), "r")
    assert cells[1:5] == ["x.toml", "150", "100", "700"]


def test_each_set_shows_average_and_normal_from_its_summary_and_a_missing_set_a_dash(tmp_path):
    run = make_run(tmp_path / "r", stages={"finetune": 5}, summaries={"procedural-64": {"adaptive": (0.0444, 0.0208)}})
    cells = row(study.table([(run, None)]), "r")
    assert cells[4] == "5" and cells[3] == "-"  # a continued chain: no initializer stage
    assert cells[7] == "-" and cells[8] == "0.0444 (0.0208)"


def test_a_score_is_bold_only_where_average_and_normal_both_meet_their_goals(tmp_path):
    both = make_run(tmp_path / "both", stages={"init": 1}, demo=(0.035, 0.05))  # on the goals: met
    one = make_run(tmp_path / "one", stages={"init": 1}, demo=(0.030, 0.051))
    text = study.table([(both, None), (one, None)])
    assert row(text, "both")[5] == "**0.0350 (0.0500)**"
    assert row(text, "one")[5] == "0.0300 (0.0510)"


def test_a_set_without_a_goal_is_never_bold(tmp_path):
    run = make_run(tmp_path / "r", stages={"init": 1}, summaries={"procedural-64": {"adaptive": (0.001, 0.001)}})
    assert row(study.table([(run, None)]), "r")[8] == "0.0010 (0.0010)"


def test_a_summary_of_several_exports_needs_the_method_named_and_gives_its_row(tmp_path):
    run = make_run(tmp_path / "r", stages={"finetune": 1},
                   summaries={"samples-256": {"adaptive": (0.06, 0.05), "c15": (0.04, 0.03)}})
    with pytest.raises(ValueError, match="scores adaptive, c15: name one as DIR:METHOD"):
        study.table([(run, None)])
    assert row(study.table([study.parse_run(f"{run}:c15")]), "r:c15")[6] == "**0.0400 (0.0300)**"
    with pytest.raises(ValueError, match="no row of method 'c16'"):
        study.table([(run, "c16")])


def test_a_folder_with_several_demo_records_is_refused(tmp_path):
    run = make_run(tmp_path / "r", stages={"init": 1})
    (run / "demo-y.json").write_text((run / "demo-x.json").read_text())
    with pytest.raises(ValueError, match="2 demo records"):
        study.table([(run, None)])


def test_a_folder_without_a_chain_record_is_refused(tmp_path):
    (tmp_path / "r").mkdir()
    with pytest.raises(ValueError, match="no records/chain.json"):
        study.table([(tmp_path / "r", None)])
