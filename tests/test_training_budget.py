"""Time-budgeted training and the chain: per-map loss weights, durations, the budget's schedule
and end, export on a signal, and ``train-chain`` (budget split, resume, provenance)."""

import json
import math
import signal
from pathlib import Path

import pytest
import torch

from mitsvbrdf.losses import map_l1
from mitsvbrdf.training import ConfigError, Trainer, TrainingInterrupted, load_config
from mitsvbrdf.training.chain import load_chain, run_chain, stage_dir
from mitsvbrdf.training.config import parse_duration

ROOT = Path(__file__).resolve().parents[1]
# deterministic LTC rendering at 8 px: a run costs well under a second a step
FAST = {"data": {"size": 8}, "render": {"method": "ltc", "ltc_mode": "prefiltered"}}


@pytest.fixture(autouse=True)
def _threads(one_torch_thread):
    pass


def budgeted(out: Path, budget: float, steps: int = 100_000, **loss) -> object:
    return load_config(table={"stage": "init", "seed": 0, "out": str(out), **FAST, "model": {"initializer_width": 4},
                              "loss": loss, "train": {"steps": steps, "batch": 2, "log_every": 1,
                                                      "checkpoint_every": 1000, "lr": 1e-3,
                                                      "time_budget": budget}})


# ---- per-map loss weights -------------------------------------------------------------------


def test_plain_map_weights_are_the_papers_mean_absolute_error():
    a, b = torch.rand(2, 10, 4, 4), torch.rand(2, 10, 4, 4)
    assert torch.equal(map_l1(a, b), (a - b).abs().mean())


def test_map_weights_scale_each_maps_channels():
    a, b = torch.zeros(1, 10, 2, 2), torch.ones(1, 10, 2, 2)
    # normal 3 channels x 5, diffuse 3 x 1, roughness 1 x 2, specular 3 x 0, mean over 10 channels
    assert float(map_l1(a, b, [5.0, 1.0, 2.0, 0.0])) == pytest.approx((15 + 3 + 2 + 0) / 10)


@pytest.mark.parametrize("weights", [[1.0, 1.0, 1.0], [-1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0]])
def test_bad_map_weights_are_a_config_error_naming_the_key(tmp_path, weights):
    with pytest.raises(ConfigError, match=r"loss\.map_weights"):
        budgeted(tmp_path, 1.0, map_weights=weights)


# ---- durations and the budget ---------------------------------------------------------------


@pytest.mark.parametrize("text,seconds", [("2h", 7200), ("90m", 5400), ("1h30m", 5400), ("45s", 45), ("120", 120),
                                          (30, 30)])
def test_durations_read_as_seconds(text, seconds):
    assert parse_duration(text) == seconds


@pytest.mark.parametrize("text", ["", "soon", "-5m", "0", "2d"])
def test_bad_durations_are_refused_with_the_forms_it_accepts(text):
    with pytest.raises(ConfigError, match="time budget"):
        parse_duration(text)


def test_budget_schedule_is_the_cosine_of_the_elapsed_fraction(tmp_path):
    t = Trainer(budgeted(tmp_path, 100.0), progress=False)
    for elapsed, want in ((0.0, 1e-3), (50.0, 0.5e-3), (100.0, 0.0), (250.0, 0.0)):
        t.elapsed = elapsed
        t._budget_lr()
        assert t.opt.param_groups[0]["lr"] == pytest.approx(want, abs=1e-15)


def test_a_budgeted_train_command_that_hits_its_step_cap_says_so(tmp_path, capsys):
    from mitsvbrdf.cli import main

    cfg = tmp_path / "tiny.toml"
    cfg.write_text('stage = "init"\nseed = 0\n[data]\nsize = 8\n[render]\nmethod = "ltc"\nltc_mode = "prefiltered"\n'
                   '[model]\ninitializer_width = 4\n[train]\nsteps = 2\nbatch = 2\nlog_every = 1\n')
    assert main(["train", str(cfg), "--out", str(tmp_path / "run"), "--time-budget", "1h", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "stopped at train.steps = 2" in err and "3600 s time budget" in err


def test_budgeted_run_ends_when_the_budget_is_spent_and_exports(tmp_path):
    budget = 1.5
    t = Trainer(budgeted(tmp_path, budget), progress=False)
    last = t.run()
    assert t.finished and 0 < t.step < 100_000
    assert budget <= t.elapsed < budget + 5 * t.elapsed / t.step  # ends at the first step past the budget
    assert (tmp_path / "networks.pt").is_file()
    # each step ran at the cosine of the time spent before it (the previous row's seconds, rounded
    # to 0.01 s in the log, which bounds the rate's error by lr0 pi/2 0.005 / budget)
    rows = t.history
    tol = 1e-3 * math.pi / 2 * 0.005 / budget * 1.01
    for prev, row in zip(rows, rows[1:]):
        f = min(prev["seconds"] / budget, 1.0)
        assert row["lr"] == pytest.approx(1e-3 * 0.5 * (1 + math.cos(math.pi * f)), abs=tol)
    assert last == rows[-1]
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert ck["finished"] and ck["elapsed"] == pytest.approx(t.elapsed)


def test_progress_of_a_budgeted_run_counts_seconds_of_its_budget_and_shows_the_step(tmp_path, capsys):
    Trainer(budgeted(tmp_path, 3600.0, steps=3), progress=True).run()
    err = capsys.readouterr().err
    assert "/3600" in err and "step=3" in err
    assert "/3 " not in err  # not the step bound


def test_steps_stay_an_upper_bound_under_a_budget(tmp_path):
    t = Trainer(budgeted(tmp_path, 3600.0, steps=3), progress=False)
    t.run()
    assert t.step == 3 and t.finished and t.elapsed < 3600


def test_resume_with_a_larger_budget_continues_from_the_recorded_time(tmp_path):
    t = Trainer(budgeted(tmp_path, 1.0), progress=False)
    t.run()
    first_step, first_elapsed = t.step, t.elapsed
    r = Trainer(budgeted(tmp_path, first_elapsed + 1.0), resume=True, progress=False)
    assert r.elapsed == pytest.approx(first_elapsed)
    r.run()
    assert r.step > first_step and r.elapsed >= first_elapsed + 1.0 - 1e-9


def test_a_signal_exports_the_networks_with_the_checkpoint(tmp_path):
    t = Trainer(budgeted(tmp_path, 3600.0), progress=False)
    t._handle(signal.SIGTERM, None)  # as if the signal arrived during the first step
    with pytest.raises(TrainingInterrupted):
        t.run()
    assert t.step == 1 and (tmp_path / "networks.pt").is_file()
    assert not torch.load(tmp_path / "checkpoint.pt", weights_only=True)["finished"]


# ---- the chain ------------------------------------------------------------------------------


def write_chain(tmp_path: Path, budget: str = "4s", shares=(1.0, 3.0)) -> Path:
    """A two-stage chain (init -> stage1) on the small configs at 8 px."""
    p = tmp_path / "chain.toml"
    sets = '"data.size=8", "render.method=\\"ltc\\"", "render.ltc_mode=\\"prefiltered\\"", "train.batch=2", ' \
           '"train.log_every=1"'
    p.write_text(f'out = "{tmp_path / "out"}"\ntime_budget = "{budget}"\nset = [{sets}]\n'
                 f'[[stages]]\nconfig = "{ROOT / "train" / "init-small.toml"}"\nshare = {shares[0]}\n'
                 f'set = ["model.initializer_width=4"]\n'
                 f'[[stages]]\nconfig = "{ROOT / "train" / "stage1-small.toml"}"\nshare = {shares[1]}\n'
                 f'set = ["model.lighting_width=4", "model.point_hidden=8"]\n')
    return p


def test_chain_splits_its_budget_by_shares_and_ships_the_last_export(tmp_path):
    chain = load_chain(write_chain(tmp_path))
    record = run_chain(chain, progress=False)
    first, second = record["stages"]
    assert first["budget_s"] == pytest.approx(1.0, abs=0.05)
    # the second stage gets what the first left: 4 s minus the first's own time
    assert second["budget_s"] == pytest.approx(4.0 - first["elapsed_s"], abs=0.1)
    assert record["training_s"] == pytest.approx(first["elapsed_s"] + second["elapsed_s"], abs=0.1)
    assert set(torch.load(chain.out / "networks.pt", weights_only=True)) >= {"l0", "initializer", "lighting"}
    written = json.loads((chain.out / "chain.json").read_text())
    assert written["commit"] and written["command"] and written["time_budget_s"] == 4.0
    assert "/" not in written["command"].split()[0]  # the program's name, not this machine's path to it


def test_chain_stage_starts_from_the_previous_stages_export(tmp_path):
    chain = load_chain(write_chain(tmp_path))
    run_chain(chain, progress=False)
    init = torch.load(stage_dir(chain, 0) / "networks.pt", weights_only=True)
    final = torch.load(chain.out / "networks.pt", weights_only=True)
    for k, v in init["l0"]["state"].items():  # L_0 is frozen after init
        assert torch.equal(v, final["l0"]["state"][k])


def test_chain_resumes_where_it_stopped_and_skips_finished_stages(tmp_path):
    chain = load_chain(write_chain(tmp_path, budget="2s", shares=(1.0, 1.0)))
    cut = run_chain(chain, progress=False, stop_after=2, extra=[])  # stops inside the first stage
    assert cut["stages"] == [] and not (chain.out / "networks.pt").exists()
    record = run_chain(chain, progress=False)
    assert [s["stage"] for s in record["stages"]] == ["init", "stage1"]
    steps = record["stages"][0]["steps"]
    again = run_chain(chain, progress=False)  # all finished: nothing trains again
    assert again["stages"][0]["steps"] == steps and again["stages"][1]["steps"] == record["stages"][1]["steps"]


@pytest.mark.parametrize("text,match", [
    ('time_budget = "1h"\n', "stages"),
    ('[[stages]]\nconfig = "nope.toml"\nshare = 1\n', "time_budget"),
    ('time_budget = "1h"\n[[stages]]\nconfig = "nope.toml"\nshare = 1\n', "does not exist"),
    ('time_budget = "1h"\n[[stages]]\nconfig = "x"\nshare = 0\n', "share"),
    ('time_budget = "1h"\nbudget = 3\n', "unknown key 'budget'"),
])
def test_bad_chain_files_are_refused_naming_the_problem(tmp_path, text, match):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_chain(p)


def test_a_stage_left_without_time_still_trains_one_step(tmp_path):
    # shares that leave the second stage nothing once the first overruns by its last step
    chain = load_chain(write_chain(tmp_path, budget="1s", shares=(1.0, 1e-9)))
    record = run_chain(chain, progress=False)
    assert record["stages"][1]["steps"] >= 1 and (chain.out / "networks.pt").is_file()
