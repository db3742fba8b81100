"""Training configs that extend shared bases (``extends``), and the shipped train/ built on them."""

import shutil
from pathlib import Path

import pytest

from mitsvbrdf.training import ConfigError, load_config
from mitsvbrdf.training.config import config_table, read_table

from conftest import benchmark_module

ROOT = Path(__file__).resolve().parents[1]
BASELINES = ("monograd", "colorgrad", "picked", "pca", "optimized", "lpl", "flash")
ADAPTIVE = ("", "-nospec", "-diffinit")


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


# ---- extends -------------------------------------------------------------------------------


def test_the_including_file_wins_over_its_base(tmp_path):
    write(tmp_path, "base.toml", 'stage = "init"\n[train]\nsteps = 10\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = "base.toml"\n[train]\nsteps = 20\n'))
    assert cfg.train.steps == 20


def test_tables_merge_key_by_key(tmp_path):
    write(tmp_path, "base.toml", 'stage = "init"\n[train]\nsteps = 10\nbatch = 3\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = "base.toml"\n[train]\nsteps = 20\n'))
    assert (cfg.train.steps, cfg.train.batch) == (20, 3)


def test_a_list_value_is_replaced_not_merged(tmp_path):
    write(tmp_path, "base.toml", 'stage = "init"\n[data]\nfamilies = ["wood", "metal"]\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = "base.toml"\n[data]\nfamilies = ["fabric"]\n'))
    assert cfg.data.families == ["fabric"]


def test_a_list_of_bases_applies_in_order_the_later_winning(tmp_path):
    write(tmp_path, "a.toml", 'stage = "init"\nseed = 1\n[train]\nsteps = 10\n')
    write(tmp_path, "b.toml", "seed = 2\n")
    cfg = load_config(write(tmp_path, "c.toml", 'extends = ["a.toml", "b.toml"]\n'))
    assert (cfg.seed, cfg.train.steps) == (2, 10)


def test_a_base_may_extend_another_relative_to_itself(tmp_path):
    write(tmp_path, "base/common.toml", 'stage = "init"\n[train]\nbatch = 3\n')
    write(tmp_path, "base/init.toml", 'extends = "common.toml"\n[train]\nsteps = 10\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = "base/init.toml"\nseed = 5\n'))
    assert (cfg.train.batch, cfg.train.steps, cfg.seed) == (3, 10, 5)


def test_a_base_reached_twice_is_not_a_cycle(tmp_path):
    write(tmp_path, "common.toml", 'stage = "init"\n')
    write(tmp_path, "a.toml", 'extends = "common.toml"\nseed = 1\n')
    write(tmp_path, "b.toml", 'extends = "common.toml"\n[train]\nsteps = 10\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = ["a.toml", "b.toml"]\n'))
    assert (cfg.seed, cfg.train.steps) == (1, 10)


def test_overrides_apply_to_the_merged_table(tmp_path):
    write(tmp_path, "base.toml", 'stage = "init"\n[train]\nsteps = 10\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = "base.toml"\n'), ["train.steps=7"])
    assert cfg.train.steps == 7


def test_the_recorded_config_holds_the_merged_values_and_reproduces_the_config(tmp_path):
    write(tmp_path, "base.toml", 'stage = "stage2"\n[model]\nsvbrdf_width = 8\n[train]\nsteps = 10\n')
    cfg = load_config(write(tmp_path, "c.toml", 'extends = "base.toml"\n[model]\nuse_spec = false\n'))
    recorded = config_table(cfg)
    assert "extends" not in recorded
    assert load_config(table=recorded) == cfg


def test_read_table_leaves_no_extends_key(tmp_path):
    write(tmp_path, "base.toml", 'stage = "init"\n')
    assert read_table(write(tmp_path, "c.toml", 'extends = "base.toml"\nseed = 1\n')) == {"stage": "init", "seed": 1}


def test_a_missing_base_is_refused_in_one_line_naming_the_chain_of_files(tmp_path):
    write(tmp_path, "base/mid.toml", 'extends = "gone.toml"\n')
    c = write(tmp_path, "c.toml", 'extends = "base/mid.toml"\n')
    with pytest.raises(ConfigError) as e:
        load_config(c)
    assert str(e.value) == f"{c} -> {tmp_path / 'base/mid.toml'} -> {tmp_path / 'base/gone.toml'}: no such config file"


def test_a_cycle_of_extends_is_refused_in_one_line_naming_the_cycle(tmp_path):
    a = write(tmp_path, "a.toml", 'stage = "init"\nextends = "b.toml"\n')
    write(tmp_path, "b.toml", 'extends = "a.toml"\n')
    with pytest.raises(ConfigError) as e:
        load_config(a)
    assert str(e.value) == f"{a} -> {tmp_path / 'b.toml'} -> {a}: extends cycle"


def test_a_file_extending_itself_is_a_cycle(tmp_path):
    a = write(tmp_path, "a.toml", 'stage = "init"\nextends = "a.toml"\n')
    with pytest.raises(ConfigError, match="extends cycle"):
        load_config(a)


def test_a_base_that_is_not_toml_is_named_with_the_chain(tmp_path):
    write(tmp_path, "base.toml", "stage = \n")
    c = write(tmp_path, "c.toml", 'extends = "base.toml"\n')
    with pytest.raises(ConfigError) as e:
        load_config(c)
    assert str(e.value).startswith(f"{c} -> {tmp_path / 'base.toml'}: not valid TOML (")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("value", ["3", '[1, "a.toml"]', '{ file = "a.toml" }'])
def test_extends_that_is_not_file_names_is_refused(tmp_path, value):
    c = write(tmp_path, "c.toml", f'stage = "init"\nextends = {value}\n')
    with pytest.raises(ConfigError, match=r"c\.toml: extends: expected a file name or a list of file names"):
        load_config(c)


def test_a_ready_table_cannot_extend():
    with pytest.raises(ConfigError, match="extends: only a config file can extend"):
        load_config(table={"stage": "init", "extends": "base.toml"})


def test_an_override_cannot_extend(tmp_path):
    c = write(tmp_path, "c.toml", 'stage = "init"\n')
    with pytest.raises(ConfigError, match="extends: only a config file can extend"):
        load_config(c, ['extends="base.toml"'])


# ---- the shipped train/: one G_sc budget per scale ------------------------------------------


@pytest.mark.parametrize("suffix, scale", [("-small", "small"), ("", "full")])
def test_changing_the_budget_in_the_bases_changes_every_baseline_and_adaptive_chain_alike(tmp_path, suffix, scale):
    train = tmp_path / "train"
    shutil.copytree(ROOT / "train", train)
    base = load_config(train / "base" / f"fixed-{scale}.toml").train.steps
    stage2 = load_config(train / "base" / f"stage2-{scale}.toml").train.steps
    # a budget larger by 1000: all of it to the fine-tuning, so stage 2 stays as it is
    for name, new in ((f"fixed-{scale}.toml", base + 1000), (f"finetune-{scale}.toml", base + 1000 - stage2)):
        path = train / "base" / name
        text = path.read_text()
        old = f"steps = {load_config(path).train.steps}\n"
        assert text.count(old) == 1, name
        path.write_text(text.replace(old, f"steps = {new}\n"))
    cfg = lambda name: load_config(train / f"{name}{suffix}.toml")  # noqa: E731
    budgets = {f"fixed-{b}": cfg(f"fixed-{b}").train.steps for b in BASELINES}
    budgets |= {f"adaptive{a}": cfg(f"stage2{a}").train.steps + cfg(f"finetune{a}").train.steps for a in ADAPTIVE}
    assert budgets == dict.fromkeys(budgets, base + 1000)


# ---- benchmarks/table3.py's "medium" scale: the CPU configs at the shipped weights' recipe ------


def table3_plan(scale: str):
    """benchmarks/table3.py's runs at ``scale``: the configs as each run loads them, by run name."""
    table3 = benchmark_module("table3")
    return table3, {r.name: load_config(r.config, r.overrides) for r in table3.plan(scale, 1.0).values()}


def test_table3_medium_trains_every_run_on_the_shipped_recipes_data_and_loss():
    table3, cfgs = table3_plan("medium")
    assert {c.data.size for c in cfgs.values()} == {64}
    assert {tuple(c.loss.map_weights) for c in cfgs.values()} == {(5.0, 1.0, 1.0, 1.0)}
    assert {c.render.spp for c in cfgs.values()} == {4}
    assert cfgs["init"].model.initializer_width == 16


def test_table3_medium_gives_every_method_the_same_g_sc_and_budget():
    table3, cfgs = table3_plan("medium")
    g_sc = {n: c for n, c in cfgs.items() if c.stage in ("stage2", "finetune", "fixed")}
    assert {c.model.svbrdf_width for c in g_sc.values()} == {16}
    assert {c.model.diffuse_ratio for n, c in g_sc.items() if n != "fixed-flash"} == {True}
    budgets = {f"fixed-{b}": cfgs[f"fixed-{b}"].train.steps for b in BASELINES}
    budgets |= {f"adaptive{a}": cfgs[f"stage2{a}"].train.steps + cfgs[f"finetune{a}"].train.steps for a in ADAPTIVE}
    assert len(set(budgets.values())) == 1, budgets


def test_table3_medium_flash_baseline_takes_no_diffuse_ratio_inputs():
    # the flash stage refuses them: with the LCD off there is no L^d (FixedStage)
    _, cfgs = table3_plan("medium")
    assert cfgs["fixed-flash"].model.light == "flash"
    assert cfgs["fixed-flash"].model.diffuse_ratio is False


def test_table3_medium_runs_start_from_medium_runs_only():
    table3, _ = table3_plan("medium")
    runs = table3.plan("medium", 1.0)
    assert all(k.endswith("-medium") for k in runs)
    assert all(r.parent in runs for r in runs.values() if r.parent)


# ---- benchmarks/gsc_sample_efficiency.py: G_sc arms that differ in their own settings only ------


def gsc_arms(tmp_path):
    study = benchmark_module("gsc_sample_efficiency")
    runs = study.plan(list(study.ARMS), 6000, tmp_path)
    return {a: load_config(r.config, r.overrides) for a, r in runs.items()}


def test_gsc_sample_efficiency_arms_differ_only_in_learning_rate_map_weights_and_clipping(tmp_path):
    import dataclasses

    cfgs = gsc_arms(tmp_path)

    def rest(c):
        d = dataclasses.asdict(c)
        d.pop("out")
        d["train"].pop("lr")
        d["loss"].pop("map_weights")
        d["train"].pop("grad_clip")
        return d

    first, *others = cfgs.values()
    assert all(rest(c) == rest(first) for c in others)
    recipe = (5.0, 1.0, 1.0, 1.0)
    assert {a: (c.train.lr, tuple(c.loss.map_weights), c.train.grad_clip) for a, c in cfgs.items()} == {
        "lr1e-3": (1e-3, recipe, 1.0), "lr2e-3": (2e-3, recipe, 1.0), "lr4e-3": (4e-3, recipe, 1.0),
        "lr5e-4": (5e-4, recipe, 1.0), "rough3": (1e-3, (5.0, 1.0, 3.0, 1.0), 1.0),
        "plain": (1e-3, (1.0, 1.0, 1.0, 1.0), 1.0), "noclip": (1e-3, recipe, 0.0)}


def test_gsc_sample_efficiency_trains_the_shipped_g_sc_for_the_steps_asked(tmp_path):
    cfgs = gsc_arms(tmp_path)
    c = cfgs["lr1e-3"]
    assert (c.stage, c.data.size, c.render.spp, c.model.svbrdf_width, c.model.diffuse_ratio) == ("fixed", 64, 4, 16, True)
    assert (c.train.steps, list(c.data.bump), c.data.dark_metals) == (6000, [1.0, 8.0], 0.5)
    assert {str(c.out) for c in cfgs.values()} == {str(tmp_path / a) for a in cfgs}
