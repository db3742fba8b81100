"""Training: configs, stages (gradients through Mitsuba), the driver (resume, signals, DDP, outputs)."""

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.data.procedural import generate
from mitsvbrdf.losses import PLAIN_MAP_WEIGHTS, map_l1
from mitsvbrdf.nets import network_record
from mitsvbrdf.relight import FlashLight
from mitsvbrdf.training import STAGES, ConfigError, RenderSettings, Trainer, TrainingError, load_config, train

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _threads(one_torch_thread):
    pass


def tiny(stage: str, out: Path, steps: int = 3, extra=(), **model) -> object:
    table = {"stage": stage, "seed": 0, "out": str(out), "data": {"size": 32},
             "render": {"method": "mitsuba", "spp": 1},
             "train": {"steps": steps, "batch": 2, "log_every": 1, "checkpoint_every": 2, "lr": 1e-3},
             "model": model}
    return load_config(table=table, overrides=list(extra))


# ---- configs -------------------------------------------------------------------------------


def test_every_shipped_config_validates():
    for path in sorted((ROOT / "train").glob("*.toml")):
        load_config(path)


def test_every_shipped_chain_validates_with_its_stage_configs():
    from mitsvbrdf.training.chain import load_chain

    for path in sorted((ROOT / "train" / "chains").glob("*.toml")):
        chain = load_chain(path)
        for st in chain.stages:
            load_config(st.config, [*chain.overrides, *st.overrides])


def test_every_warm_start_of_a_shipped_chain_finds_its_networks_in_the_file(rig):
    from mitsvbrdf.nets.io import read_network_file
    from mitsvbrdf.training.chain import load_chain

    started = 0
    for path in sorted((ROOT / "train" / "chains").glob("*.toml")):
        chain = load_chain(path)
        for st in chain.stages:
            cfg = load_config(st.config, [*chain.overrides, *st.overrides])
            if cfg.pretrained.warm_start:
                stage = STAGES[cfg.stage](cfg.model, cfg.loss, RenderSettings(), rig)
                stage.warm_start(read_network_file(ROOT / cfg.pretrained.warm_start, "networks"))
                started += 1
    assert started >= 2  # continue-small.toml: G_l in stage 1, G_sc in stage 2


@pytest.mark.parametrize("suffix", ["-small", ""])
def test_every_baseline_and_adaptive_variant_gets_the_same_g_sc_budget(suffix):
    cfg = lambda name: load_config(ROOT / "train" / f"{name}{suffix}.toml")  # noqa: E731
    budgets = {chain: cfg(f"stage2{chain}").train.steps + cfg(f"finetune{chain}").train.steps
               for chain in ("", "-nospec", "-diffinit")}
    budgets |= {b: cfg(f"fixed-{b}").train.steps
                for b in ("monograd", "colorgrad", "picked", "pca", "optimized", "lpl", "flash")}
    assert len(set(budgets.values())) == 1, budgets
    batches = {cfg(n).train.batch for n in ("stage2", "finetune", "fixed-monograd", "fixed-flash")}
    assert len(batches) == 1


def test_unknown_key_is_named_with_a_suggestion():
    with pytest.raises(ConfigError, match=r"train\.stpes: unknown key \(did you mean 'steps'\?\)"):
        load_config(table={"stage": "init", "train": {"stpes": 3}})


def test_wrong_type_is_named():
    with pytest.raises(ConfigError, match=r"train\.lr: expected float, got str"):
        load_config(table={"stage": "init", "train": {"lr": "fast"}})


def test_unknown_model_key_of_the_stage_is_named():
    with pytest.raises(ConfigError, match=r"model\.lighting_widht: unknown key"):
        load_config(table={"stage": "stage1", "model": {"lighting_widht": 4}})


@pytest.mark.parametrize("bump, source", [("[4.0, 1.0]", "procedural"), ("[0.0, 1.0]", "procedural"),
                                          ("[2.0]", "procedural"), ("[1.0, 2.0]", "strips")])
def test_a_bump_range_that_is_not_a_relief_range_of_procedural_data_is_refused(bump, source):
    with pytest.raises(ConfigError, match=r"data\.bump: must be"):
        load_config(ROOT / "train" / "stage2-small.toml", [f"data.bump={bump}", f'data.source="{source}"'])


def test_the_bump_range_reaches_the_procedural_dataset():
    from mitsvbrdf.training.trainer import make_dataset

    cfg = load_config(ROOT / "train" / "stage2-small.toml", ["data.bump=[1.0, 4.0]"])
    assert make_dataset(cfg).bump == (1.0, 4.0)


@pytest.mark.parametrize("fraction, source", [("-0.1", "procedural"), ("1.5", "procedural"), ("0.25", "strips")])
def test_a_dark_metal_fraction_outside_0_1_or_for_loaded_data_is_refused(fraction, source):
    with pytest.raises(ConfigError, match=r"data\.dark_metals: must be"):
        load_config(ROOT / "train" / "stage2-small.toml", [f"data.dark_metals={fraction}", f'data.source="{source}"'])


def test_the_dark_metal_fraction_reaches_the_procedural_dataset():
    from mitsvbrdf.training.trainer import make_dataset

    cfg = load_config(ROOT / "train" / "stage2-small.toml", ["data.dark_metals=0.25"])
    assert make_dataset(cfg).dark_metals == 0.25


@pytest.mark.parametrize("crop_from", [32, 20, -8])
def test_windows_from_materials_not_larger_than_them_are_refused(crop_from):
    with pytest.raises(ConfigError, match=r"data\.crop_from: must be"):
        load_config(ROOT / "train" / "stage2-small.toml", ["data.size=32", f"data.crop_from={crop_from}"])


def test_each_step_trains_on_a_window_of_the_larger_materials_rendered_where_it_sits(tmp_path, rig):
    from mitsvbrdf.data.datasets import collate_svbrdf
    from mitsvbrdf.training.trainer import step_seed, window_of_step

    t = Trainer(tiny("init", tmp_path / "run", extra=["data.size=16", "data.crop_from=32"]), progress=False)
    got = t.batch(3)
    top, left = window_of_step(32, 16, step_seed(0, 3, 0))
    whole = collate_svbrdf([t.dataset[i] for i in (6, 7)])  # step 3 of batch 2
    assert whole.resolution == (32, 32) and got.resolution == (16, 16)
    torch.testing.assert_close(got.normal, whole.normal[..., top:top + 16, left:left + 16], rtol=0, atol=0)
    torch.testing.assert_close(t.stage.rig.surface_points(16), rig.surface_points(32)[top:top + 16, left:left + 16],
                               rtol=0, atol=1e-9)
    assert len({window_of_step(32, 16, step_seed(0, s, 0)) for s in range(8)}) > 1  # the window moves


def test_integrator_options_reach_the_training_captures_through_a_copy_of_the_scene(tmp_path):
    t = Trainer(tiny("init", tmp_path / "run", extra=["render.integrator.ltc_grid=8",
                                                      'render.integrator.sampler="independent"',
                                                      "render.integrator.freeze=false"]), progress=False)
    scene = (tmp_path / "run" / "scene.xml").read_text()
    assert t.rig.source == t.stage.rig.source == str(tmp_path / "run" / "scene.xml")
    assert '<integer name="ltc_grid" value="8"' in scene and '<string name="sampler" value="independent"' in scene
    assert '<boolean name="freeze" value="false"' in scene
    from mitsvbrdf.render.mitsuba import load_scene, variant_for

    integrator = load_scene(str(t.rig.source), variant_for(torch.device("cpu")))[3]
    assert (integrator.ltc_grid, integrator.sampler, integrator.freeze) == (8, "independent", False)


def test_an_unknown_integrator_option_stops_the_run_before_its_first_step(tmp_path):
    with pytest.raises(ms.errors.SceneError, match="ltc_gird"):
        Trainer(tiny("init", tmp_path / "run", extra=["render.integrator.ltc_gird=8"]), progress=False)


@pytest.mark.parametrize("extra, match", [(["render.integrator.ltc_grid=[8]"], "must be a string, boolean, integer or float"),
                                          (["render.integrator.ltc_grid=8", 'render.method="ltc"'],
                                           "need render.method = 'mitsuba'")])
def test_integrator_options_that_cannot_apply_are_config_errors(extra, match):
    with pytest.raises(ConfigError, match=match):
        load_config(ROOT / "train" / "stage2-small.toml", extra)


def test_networks_trained_on_windows_record_the_grid_they_were_cut_from(tmp_path):
    sets = ["train.steps=1", "train.batch=2", "render.spp=1", "data.size=16", "data.crop_from=32",
            f'out="{tmp_path}"', f'pretrained.networks="{ROOT / "mitsvbrdf" / "weights" / "networks.pt"}"']
    train(load_config(ROOT / "train" / "stage2-small.toml", sets), progress=False)
    assert torch.load(tmp_path / "networks.pt", weights_only=True)["acquisition"]["resolution"] == 32


def test_a_warm_start_leaves_the_scratch_networks_to_the_config(tmp_path):
    shipped = ROOT / "mitsvbrdf" / "weights" / "networks.pt"
    t = Trainer(tiny("init", tmp_path / "run", initializer_width=12, train_l0=False,
                     extra=[f'pretrained.warm_start="{shipped}"', 'pretrained.scratch=["initializer"]']), progress=False)
    assert t.stage.nets["initializer"].config["width"] == 12  # the config's, not the file's
    l0 = torch.load(shipped, weights_only=True)["l0"]["state"]["logits"]
    torch.testing.assert_close(t.stage.nets["l0"].logits.detach(), l0, rtol=0, atol=0)  # still the file's


@pytest.mark.parametrize("extra", [['pretrained.scratch=["lighting"]'], ['pretrained.scratch=["initializer"]']],
                         ids=["not-trained-here", "without-warm-start"])
def test_scratch_networks_that_the_stage_does_not_train_or_without_a_warm_start_are_refused(tmp_path, extra):
    shipped = ROOT / "mitsvbrdf" / "weights" / "networks.pt"
    warm = [f'pretrained.warm_start="{shipped}"'] if "lighting" in extra[0] else []
    with pytest.raises(TrainingError, match="pretrained.scratch"):
        Trainer(tiny("init", tmp_path / "run", extra=[*warm, *extra]), progress=False)


def test_missing_or_unknown_stage_is_refused():
    with pytest.raises(ConfigError, match="stage: must be one of"):
        load_config(table={"seed": 1})


def test_overrides_set_nested_keys():
    cfg = load_config(ROOT / "train" / "init-small.toml", ["train.steps=7", "render.method=reference"])
    assert cfg.train.steps == 7 and cfg.render.method == "reference"


# ---- stages ----------------------------------------------------------------------------------


def test_gradient_reaches_the_lighting_net_through_the_mitsuba_renderer(rig):
    S = STAGES["stage1"]
    # reconstruction loss only: its gradient can reach G_l only through the rendered images
    stage = S(S.Model(lighting_width=4, point_hidden=16), S.Loss(consistency=0.0, inverse=0.0),
              RenderSettings("mitsuba", 2), rig)
    stage(generate(2, size=32, seed=0), seed=1)["loss"].backward()
    grads = [p.grad for p in stage.nets["lighting"].heads.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert sum(float(g.abs().sum()) for g in grads) > 0


@pytest.mark.parametrize("name", ["init", "stage1", "stage2", "finetune", "fixed"])
def test_each_stage_returns_finite_losses_and_gradients(rig, name):
    S = STAGES[name]
    model = {"init": dict(initializer_width=4), "fixed": dict(svbrdf_width=4)}.get(
        name, dict(lighting_width=4, point_hidden=16, svbrdf_width=4))
    stage = S(S.Model(**model), S.Loss(), RenderSettings("mitsuba", 1), rig)
    out = stage(generate(2, size=32, seed=1), seed=0)
    assert "loss" in out and all(torch.isfinite(v) for v in out.values())
    out["loss"].backward()


def test_init_lpdf_loss_is_the_l1_between_the_estimates_and_the_truths_lpdf(rig):
    from mitsvbrdf.acquisition import AcquisitionSettings, maps_to_svbrdf
    from mitsvbrdf.importance import importance
    S = STAGES["init"]
    model = S.Model(initializer_width=4, lpdf_cell_order=1, lpdf_lobe_grid=8)
    stage = S(model, S.Loss(maps=0.0, lpdf=2.0), RenderSettings("mitsuba", 1), rig)
    batch = generate(2, size=32, seed=3)
    out = stage(batch, seed=0)
    # the same I_0 again (seeded capture), decoded as an acquisition decodes it
    g = torch.Generator().manual_seed(0)
    _, i0 = stage.first_image(batch, 0, g)
    est = maps_to_svbrdf(stage.nets["initializer"](i0))
    q = AcquisitionSettings(lpdf_cell_order=1, lpdf_lobe_grid=8).lpdf_quadrature
    expected = (importance(est.normal, est.roughness, rig, texel_stride=4, settings=q)
                - importance(batch.normal, batch.roughness, rig, texel_stride=4, settings=q)).abs().mean()
    assert torch.allclose(out["lpdf"], expected, rtol=1e-5, atol=1e-7)
    assert torch.allclose(out["loss"], 2.0 * out["lpdf"])


def test_init_lpdf_loss_trains_the_initializer(rig):
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4, train_l0=False, lpdf_cell_order=1, lpdf_lobe_grid=8),
              S.Loss(maps=0.0, lpdf=1.0), RenderSettings("mitsuba", 1), rig)
    stage(generate(2, size=32, seed=4), seed=0)["loss"].backward()
    grads = [p.grad for p in stage.nets["initializer"].parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert sum(float(g.abs().sum()) for g in grads) > 0


def test_init_l0_gets_its_own_learning_rate(rig):
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4, pattern_lr=0.05), S.Loss(), RenderSettings(), rig)
    groups = stage.param_groups(1e-3)
    assert [g["lr"] for g in groups] == [1e-3, 0.05]
    assert groups[1]["params"] == [stage.nets["l0"].logits]
    assert sum(p.numel() for g in groups for p in g["params"]) == sum(p.numel() for p in stage.parameters())


def test_init_l0_rate_is_moot_while_l0_is_frozen(rig):
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4, pattern_lr=0.05, train_l0=False), S.Loss(), RenderSettings(), rig)
    assert [g["lr"] for g in stage.param_groups(1e-3)] == [1e-3]


def test_init_l0_moves_by_its_own_rate(tmp_path):
    """Adam's first step moves every parameter with a gradient by about its group's rate: L_0's
    logits by pattern_lr, not by train.lr."""
    train(tiny("init", tmp_path / "run", steps=1, initializer_width=4, pattern_lr=0.2), progress=False)
    logits = torch.load(tmp_path / "run" / "networks.pt", weights_only=True)["l0"]["state"]["logits"]
    moved = (logits - math.log(0.9 / 0.1)).abs().max()
    assert 0.1 < float(moved) <= 0.2 + 1e-4


def test_init_l0_starts_at_the_named_pattern(rig):
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4, l0_start="colorgrad[1]"), S.Loss(), RenderSettings(), rig)
    start = ms.patterns.pattern_family("colorgrad", *rig.lcd_cells)[1].clamp(1e-3, 1 - 1e-3)
    assert torch.allclose(stage.nets["l0"]()[0], start, atol=1e-6)


def test_init_l0_starts_uniform_by_default(rig):
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4), S.Loss(), RenderSettings(), rig)
    assert torch.allclose(stage.nets["l0"](), torch.full((1, 3, *rig.lcd_cells), 0.9))


def test_a_negative_init_l0_rate_is_refused(rig):
    S = STAGES["init"]
    with pytest.raises(ms.MitsvbrdfError, match="pattern_lr"):
        S(S.Model(initializer_width=4, pattern_lr=-1.0), S.Loss(), RenderSettings(), rig)


def test_init_without_the_lpdf_loss_reports_no_lpdf_term(rig):
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4), S.Loss(), RenderSettings("mitsuba", 1), rig)
    assert "lpdf" not in stage(generate(1, size=32, seed=5), seed=0)


def test_init_with_the_diffuse_ratio_input_gives_the_initializer_l0s_irradiance(rig):
    from mitsvbrdf.separation import diffuse_irradiance
    S = STAGES["init"]
    stage = S(S.Model(initializer_width=4, initializer_diffuse_ratio=True), S.Loss(), RenderSettings("mitsuba", 1), rig)
    batch = generate(2, size=32, seed=3)
    out = stage(batch, seed=0)
    l0, i0 = stage.first_image(batch, 0, torch.Generator().manual_seed(0))
    pred = stage.nets["initializer"](i0, diffuse_irradiance(l0[None], rig, 32))
    assert torch.allclose(out["maps"], map_l1(pred, batch.encoded(), PLAIN_MAP_WEIGHTS), rtol=1e-5)
    out["loss"].backward()  # L_0 learns through the image and through its irradiance
    assert torch.isfinite(stage.nets["l0"].logits.grad).all()


def test_warm_start_widens_a_plain_initializer_when_the_config_asks_for_diffuse_ratio(rig):
    S = STAGES["init"]
    plain = S(S.Model(initializer_width=4), S.Loss(), RenderSettings("mitsuba", 1), rig)
    stage = S(S.Model(initializer_width=4, initializer_diffuse_ratio=True), S.Loss(), RenderSettings("mitsuba", 1), rig)
    stage.warm_start({n: network_record(net) for n, net in plain.nets.items()})
    assert stage.nets["initializer"].diffuse_ratio
    assert torch.isfinite(stage(generate(1, size=32, seed=5), seed=0)["loss"])


def test_a_few_steps_on_one_batch_reduce_the_loss(rig):
    S = STAGES["fixed"]
    stage = S(S.Model(svbrdf_width=4), S.Loss(), RenderSettings("mitsuba", 1), rig)
    batch = generate(2, size=32, seed=2)
    opt = torch.optim.Adam(stage.parameters(), lr=3e-3)
    first = None
    for _ in range(15):
        loss = stage(batch, seed=0)["loss"]
        first = first if first is not None else float(loss.detach())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.8 * first


def test_learned_pattern_group_gets_gradients_through_the_mitsuba_renderer(rig):
    S = STAGES["fixed"]
    stage = S(S.Model(patterns="random", learn_patterns=True, svbrdf_width=4), S.Loss(), RenderSettings("mitsuba", 1),
              rig)
    stage(generate(2, size=32, seed=3), seed=0)["loss"].backward()
    g = stage.nets["patterns"].logits.grad
    assert g is not None and torch.isfinite(g).all() and float(g.abs().sum()) > 0


def test_learned_patterns_get_their_own_learning_rate(rig):
    S = STAGES["fixed"]
    stage = S(S.Model(patterns="random", learn_patterns=True, pattern_lr=0.05, svbrdf_width=4), S.Loss(),
              RenderSettings(), rig)
    groups = stage.param_groups(1e-3)
    assert [g["lr"] for g in groups] == [1e-3, 0.05]
    assert groups[1]["params"] == [stage.nets["patterns"].logits]
    assert sum(p.numel() for g in groups for p in g["params"]) == sum(p.numel() for p in stage.parameters())


def test_fixed_pattern_group_stays_a_buffer_without_gradients(rig):
    S = STAGES["fixed"]
    stage = S(S.Model(patterns="monograd", svbrdf_width=4), S.Loss(), RenderSettings("mitsuba", 1), rig)
    assert not list(stage.nets["patterns"].parameters())
    assert torch.equal(stage.nets["patterns"](), ms.patterns.load_patterns("monograd", *rig.lcd_cells))


def test_single_learned_pattern_is_the_lpl_baseline(rig):
    S = STAGES["fixed"]
    stage = S(S.Model(patterns="uniform", learn_patterns=True, svbrdf_width=4), S.Loss(), RenderSettings("mitsuba", 1),
              rig)
    assert stage.nets["patterns"]().shape == (1, 3, *rig.lcd_cells)
    assert stage.nets["svbrdf"].config["num_images"] == 1


def test_flash_baseline_sees_one_image_under_a_light_at_the_camera(rig):
    S = STAGES["fixed"]
    stage = S(S.Model(light="flash", svbrdf_width=4), S.Loss(), RenderSettings("mitsuba", 1), rig)
    batch = generate(2, size=32, seed=4)
    imgs = stage.nets["flash"](batch, rig)
    assert imgs.shape == (2, 1, 3, 32, 32) and float(imgs.min()) >= 0
    out = stage(batch, seed=0)
    out["loss"].backward()
    assert "patterns" not in stage.nets and torch.isfinite(out["loss"])


def test_flash_highlight_of_a_flat_glossy_sample_is_nearest_the_camera(rig):
    # light and camera coincide, so the half vector is the view direction: on a flat sample it is
    # closest to the normal at the texels nearest the camera's foot point
    glossy = ms.SVBRDF.constant(size=32, diffuse=(0.0, 0.0, 0.0), specular=(1.0, 1.0, 1.0), roughness=0.1)
    img = FlashLight()(glossy, rig)[0, 0, 0]
    pts = rig.surface_points((32, 32))
    foot = rig.camera_position[:2]
    nearest = (pts[..., :2] - foot).square().sum(-1).flatten().argmin()
    assert int(img.flatten().argmax()) == int(nearest)


def test_flash_baseline_refuses_lcd_options(rig):
    S = STAGES["fixed"]
    with pytest.raises(ms.MitsvbrdfError, match="flash"):
        S(S.Model(light="flash", learn_patterns=True), S.Loss(), RenderSettings(), rig)
    with pytest.raises(ms.MitsvbrdfError, match="diffuse_ratio must be false"):
        S(S.Model(light="flash", diffuse_ratio=True), S.Loss(), RenderSettings(), rig)
    with pytest.raises(ms.MitsvbrdfError, match="model.light"):
        S(S.Model(light="laser"), S.Loss(), RenderSettings(), rig)


def test_adaptive_stage_without_spec_uses_a_single_encoder(rig):
    S = STAGES["stage2"]
    stage = S(S.Model(lighting_width=4, svbrdf_width=4, use_spec=False), S.Loss(), RenderSettings("mitsuba", 1), rig)
    assert not stage.nets["svbrdf"].use_spec
    out = stage(generate(2, size=32, seed=5), seed=0)
    assert torch.isfinite(out["loss"])


def test_pretrained_networks_with_wrong_names_are_refused(rig):
    S = STAGES["stage1"]
    stage = S(S.Model(), S.Loss(), RenderSettings(), rig)
    with pytest.raises(ms.MitsvbrdfError, match=r"needs pretrained networks \['initializer'\]"):
        stage.load_pretrained({"l0": {}})


def _stage2(rig, **model):
    S = STAGES["stage2"]
    return S(S.Model(lighting_width=4, **{"svbrdf_width": 4, **model}), S.Loss(), RenderSettings("mitsuba", 1), rig)


def _records(stage) -> dict:
    from mitsvbrdf.nets import network_record

    for p in stage.nets["svbrdf"].parameters():  # unlike a fresh net's
        p.data.normal_(0, 0.3)
    return {n: network_record(net) for n, net in stage.nets.items()}


def test_warm_start_starts_the_networks_a_stage_builds_from_the_files(rig):
    records = _records(_stage2(rig))
    stage = _stage2(rig, svbrdf_width=8)
    stage.warm_start(records)
    net = stage.nets["svbrdf"]
    assert net.config["width"] == 4  # the file's architecture wins over the config's
    assert all(torch.equal(v, records["svbrdf"]["state"][k]) for k, v in net.state_dict().items())
    assert all(p.requires_grad for p in net.parameters())


def test_warm_start_widens_a_plain_svbrdf_predictor_when_the_config_asks_for_diffuse_ratio(rig):
    records = _records(_stage2(rig))
    stage = _stage2(rig, diffuse_ratio=True)
    stage.warm_start(records)
    assert stage.nets["svbrdf"].diffuse_ratio
    out = stage(generate(1, size=32, seed=5), seed=0)
    assert torch.isfinite(out["loss"])


def test_warm_start_from_a_file_without_the_stages_networks_is_a_clear_error(rig):
    records = _records(_stage2(rig))
    with pytest.raises(ms.MitsvbrdfError, match=r"warm_start: the file has none of the networks stage 'stage2'"):
        _stage2(rig).warm_start({"l0": records["l0"]})


def _exported_init(tmp_path) -> Path:
    """An init export whose L_0 is not the fresh pattern (uniform 0.9) and whose initializer is trained."""
    train(tiny("init", tmp_path / "first", steps=2, initializer_width=4, extra=["train.lr=0.3"]), progress=False)
    return tmp_path / "first" / "networks.pt"


def test_init_with_frozen_l0_continues_the_initializer_under_the_warm_starts_pattern(tmp_path):
    export = torch.load(_exported_init(tmp_path), weights_only=True)
    train(tiny("init", tmp_path / "cont", steps=2, initializer_width=4, train_l0=False,
                         extra=[f'pretrained.warm_start="{tmp_path / "first" / "networks.pt"}"']), progress=False)
    after = torch.load(tmp_path / "cont" / "networks.pt", weights_only=True)
    assert torch.equal(after["l0"]["state"]["logits"], export["l0"]["state"]["logits"])
    assert not torch.equal(after["initializer"]["state"]["net.decoder.ending.weight"],
                           export["initializer"]["state"]["net.decoder.ending.weight"])


def test_init_trains_l0_by_default_after_a_warm_start(tmp_path):
    export = torch.load(_exported_init(tmp_path), weights_only=True)
    train(tiny("init", tmp_path / "cont", steps=2, initializer_width=4,
               extra=[f'pretrained.warm_start="{tmp_path / "first" / "networks.pt"}"']), progress=False)
    after = torch.load(tmp_path / "cont" / "networks.pt", weights_only=True)
    assert not torch.equal(after["l0"]["state"]["logits"], export["l0"]["state"]["logits"])


def test_missing_warm_start_file_is_a_clear_error(tmp_path):
    with pytest.raises(TrainingError, match="warm_start"):
        Trainer(tiny("fixed", tmp_path, extra=[f'pretrained.warm_start="{tmp_path / "none.pt"}"'], svbrdf_width=4),
                progress=False)


# ---- the driver ------------------------------------------------------------------------------


def _params(out: Path) -> dict:
    return torch.load(out / "checkpoint.pt", weights_only=True)["stage"]


def test_run_writes_checkpoint_metrics_plot_and_networks(tmp_path):
    train(tiny("init", tmp_path, initializer_width=4), progress=False)
    for f in ("checkpoint.pt", "metrics.csv", "loss.png", "networks.pt"):
        assert (tmp_path / f).exists(), f
    assert set(torch.load(tmp_path / "networks.pt", weights_only=True)) == {"l0", "initializer"}


@pytest.fixture
def one_render_thread():
    """Dr.Jit's LLVM backend on one thread for the test. With several, the backward pass of a
    render sums the gradient of the pattern (and what flows from it) by atomic adds in the order
    the threads get there, so two equal runs can differ in the last bit of L_0's logits: seen
    under load (the full suite on 2 busy cores), never with one thread."""
    import drjit as dr

    before = dr.thread_count()
    dr.set_thread_count(1)
    yield
    dr.set_thread_count(before)


def test_resume_after_a_kill_reaches_the_same_parameters(tmp_path, one_render_thread):
    full = tiny("init", tmp_path / "full", steps=4, initializer_width=4)
    train(full, progress=False)
    cut = tiny("init", tmp_path / "cut", steps=4, initializer_width=4)
    Trainer(cut, progress=False, stop_after=1).run()  # "killed" after step 1 (checkpointed there)
    train(cut, resume=True, progress=False)
    a, b = _params(tmp_path / "full"), _params(tmp_path / "cut")
    assert all(torch.equal(a[k], b[k]) for k in a)
    la = [h["loss"] for h in torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=True)["history"]]
    lb = [h["loss"] for h in torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=True)["history"]]
    assert la == lb


def test_resume_without_a_checkpoint_is_a_clear_error(tmp_path):
    with pytest.raises(TrainingError, match="no checkpoint at"):
        Trainer(tiny("init", tmp_path / "none", initializer_width=4), resume=True, progress=False)


def test_stage_without_its_pretrained_networks_is_a_clear_error(tmp_path):
    with pytest.raises(TrainingError, match="pretrained.networks"):
        Trainer(tiny("stage1", tmp_path), progress=False)


FAST = ['render.method="ltc"', 'render.ltc_mode="prefiltered"', "data.size=8"]  # deterministic, < 1 s a run


def _init_run(out: Path, steps: int = 2) -> object:
    """The config of a finished ``steps``-step init run in ``out``."""
    cfg = tiny("init", out, steps=steps, extra=FAST, initializer_width=4)
    train(cfg, progress=False)
    return cfg


def test_training_into_a_finished_run_needs_resume_or_overwrite(tmp_path):
    cfg = _init_run(tmp_path)
    before = (tmp_path / "networks.pt").read_bytes()
    with pytest.raises(TrainingError, match="--resume.*--overwrite"):
        Trainer(cfg, progress=False)
    assert (tmp_path / "networks.pt").read_bytes() == before


def test_resume_and_overwrite_together_are_refused(tmp_path):
    with pytest.raises(TrainingError, match="choose one"):
        Trainer(tiny("init", tmp_path, extra=FAST, initializer_width=4), resume=True, overwrite=True, progress=False)


def test_overwrite_starts_the_run_again_without_the_old_files(tmp_path):
    cfg = _init_run(tmp_path)
    t = Trainer(cfg, progress=False, overwrite=True, stop_after=1)
    assert not any((tmp_path / f).exists() for f in ("networks.pt", "checkpoint.pt", "metrics.csv", "loss.png"))
    t.run()
    assert torch.load(tmp_path / "checkpoint.pt", weights_only=True)["step"] == 1


@pytest.mark.parametrize("change", ["train.lr=0.5", 'render.method="reference"', "seed=7", "model.initializer_width=8",
                                    "loss.maps=2.0", "data.size=16"])
def test_resume_refuses_changed_settings_in_one_line(tmp_path, change):
    _init_run(tmp_path)
    cfg = tiny("init", tmp_path, steps=2, extra=[*FAST, change], initializer_width=4)
    with pytest.raises(TrainingError, match=change.split("=")[0].replace(".", r"\.")) as e:
        Trainer(cfg, resume=True, progress=False)
    assert "\n" not in str(e.value)


def test_resume_with_more_steps_continues_to_the_new_end_at_lr_min(tmp_path):
    _init_run(tmp_path, steps=2)
    cfg = tiny("init", tmp_path, steps=4, extra=FAST, initializer_width=4)
    last = train(cfg, resume=True, progress=False)
    assert last["step"] == 4
    assert last["lr"] == pytest.approx(cfg.train.lr_min, abs=1e-12)


def test_resume_refuses_fewer_steps_than_the_checkpoint_has(tmp_path):
    _init_run(tmp_path, steps=2)
    cfg = tiny("init", tmp_path, steps=1, extra=FAST, initializer_width=4)
    with pytest.raises(TrainingError, match="at step 2"):
        Trainer(cfg, resume=True, progress=False)


def test_resume_refuses_a_truncated_checkpoint_in_one_line(tmp_path):
    cfg = _init_run(tmp_path)
    ck = tmp_path / "checkpoint.pt"
    ck.write_bytes(ck.read_bytes()[: ck.stat().st_size // 2])
    with pytest.raises(TrainingError, match="cannot be read") as e:
        Trainer(cfg, resume=True, progress=False)
    assert "\n" not in str(e.value)


def test_resume_from_tensors_that_do_not_fit_the_networks_is_one_line(tmp_path):
    # Same settings, other shapes (a checkpoint from another version of a network): 160 lines of
    # load_state_dict before.
    cfg = _init_run(tmp_path)
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    ck["stage"] = {k: torch.zeros(*v.shape[:-1], v.shape[-1] + 1) if v.ndim else v for k, v in ck["stage"].items()}
    torch.save(ck, tmp_path / "checkpoint.pt")
    with pytest.raises(TrainingError, match="does not fit these networks") as e:
        Trainer(cfg, resume=True, progress=False)
    assert "\n" not in str(e.value) and "more" in str(e.value)


class _Payload:
    """Unpickling this calls Path.touch(marker): code that runs when a pickle is read."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_resume_does_not_run_code_from_a_checkpoint(tmp_path):
    cfg = _init_run(tmp_path)
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    marker = tmp_path / "payload-ran"
    ck["history"].append({"step": _Payload(marker)})
    torch.save(ck, tmp_path / "checkpoint.pt")
    with pytest.raises(TrainingError, match="cannot be read"):
        Trainer(cfg, resume=True, progress=False)
    assert not marker.exists()


def test_checkpoints_hold_only_tensors_numbers_and_strings(tmp_path):
    _init_run(tmp_path)
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=True)  # raises on anything else
    assert ck["step"] == 2 and ck["config"]["stage"] == "init"


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_signal_checkpoints_exports_exits_128_plus_its_number_and_lists_only_written_files(tmp_path, sig, code):
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'stage = "init"\nout = "{tmp_path / "run"}"\n[data]\nsize = 8\n'
                   f'[render]\nmethod = "ltc"\nltc_mode = "prefiltered"\n[model]\ninitializer_width = 4\n'
                   f'[train]\nsteps = 100000\nbatch = 2\ncheckpoint_every = 100000\n')
    proc = subprocess.Popen([sys.executable, "-m", "mitsvbrdf", "train", str(cfg), "--quiet"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        import time

        deadline = time.time() + 120
        while not (tmp_path / "run").exists() and time.time() < deadline:
            time.sleep(0.2)
        time.sleep(1.0)  # a few steps
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, out
    assert "continue with --resume" in out
    step = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["step"]
    assert 0 < step < 100000
    listed = out.strip().splitlines()[-1].split("files in ")[-1].split(": ", 1)[1].split(", ")
    assert "checkpoint.pt" in listed and "networks.pt" in listed  # an interrupted run is usable
    assert all((tmp_path / "run" / f).is_file() for f in listed)


DDP_SCRIPT = r"""
import os, sys, torch
torch.set_num_threads(1)
from mitsvbrdf.training import load_config, Trainer
out, world = sys.argv[1], int(os.environ.get("WORLD_SIZE", "1"))
cfg = load_config(table={"stage": "fixed", "seed": 0, "out": out, "data": {"size": 32},
                         "render": {"method": "reference"}, "model": {"svbrdf_width": 4},
                         "train": {"steps": 2, "batch": 4, "log_every": 1, "checkpoint_every": 2, "lr": 1e-3,
                                   "grad_clip": 0.0}})
Trainer(cfg, progress=False).run()
"""


def test_two_gloo_processes_equal_one_process_with_the_whole_batch(tmp_path):
    script = tmp_path / "ddp.py"
    script.write_text(DDP_SCRIPT)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    subprocess.run([sys.executable, str(script), str(tmp_path / "one")], check=True, cwd=ROOT, env=env,
                   capture_output=True)
    r = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2", "--master_port=29517",
                        str(script), str(tmp_path / "two")], cwd=ROOT, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    a, b = _params(tmp_path / "one"), _params(tmp_path / "two")
    for k in a:
        assert torch.allclose(a[k], b[k], atol=1e-5, rtol=1e-4), k


def test_small_configs_run_as_a_chain_of_stages(tmp_path):
    prev = None
    for stage in ("init", "stage1", "stage2", "finetune"):
        sets = ["train.steps=2", "train.batch=2", "train.log_every=1", "render.spp=1", f'out="{tmp_path / stage}"']
        if prev:
            sets.append(f'pretrained.networks="{tmp_path / prev / "networks.pt"}"')
        last = train(load_config(ROOT / "train" / f"{stage}-small.toml", sets), progress=False)
        assert last["step"] == 2 and torch.isfinite(torch.tensor(last["loss"]))
        prev = stage
    export = torch.load(tmp_path / "finetune" / "networks.pt", weights_only=True)
    assert set(export) == {"l0", "initializer", "lighting", "svbrdf", "acquisition"}
    # the texel grid it trained on, which finer captures are reconstructed across
    assert export["acquisition"]["resolution"] == load_config(ROOT / "train" / "finetune-small.toml").data.size
