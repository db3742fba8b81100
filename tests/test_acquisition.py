"""The acquisition layer: the steps around injected networks (tiny stand-ins here), and networks
files that carry the settings they were trained with."""

from types import SimpleNamespace

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.acquisition import (SETTINGS_KEY, AcquisitionSettings, AdaptiveAcquisition, FixedAcquisition,
                                   load_adaptive, load_baseline, maps_to_svbrdf, predict)
from mitsvbrdf.errors import MitsvbrdfError
from mitsvbrdf.importance import importance
from mitsvbrdf.nets import NetworkFileError, network_record
from mitsvbrdf.render.quadrature import QuadratureSettings
from mitsvbrdf.separation import diffuse_irradiance
from mitsvbrdf.training import STAGES, RenderSettings

from conftest import textured_material


class MeanInitializer(torch.nn.Module):
    """Encoded maps from image brightness: a flat normal and roughness = 1 - mean brightness."""

    def forward(self, i0):
        b, _, h, w = i0.shape
        bright = (i0.mean(1, keepdim=True) / i0.mean().clamp_min(1e-6)).clamp(0, 1)
        out = torch.full((b, 10, h, w), 0.5)
        out[:, 2:3] = 1.0
        out[:, 6:7] = 1 - 0.5 * bright
        return out


class LpdfLighting(torch.nn.Module):
    """Four patterns: L_pdf itself and three colourings of it (the patterns follow L_pdf)."""

    def forward(self, i0, lpdf):
        tint = torch.tensor([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        return SimpleNamespace(patterns=lpdf[:, None] * tint.view(1, 4, 3, 1, 1))


class ImageReconstructor(torch.nn.Module):
    """Diffuse albedo from the first image; records whether it was given I^spec."""

    def forward(self, images, spec):
        b, _, _, h, w = images.shape
        self.saw_spec = spec is not None
        out = torch.full((b, 10, h, w), 0.5)
        out[:, 3:6] = (images[:, 0] / images[:, 0].amax((1, 2, 3), keepdim=True)).clamp(0, 1)
        return out


@pytest.fixture()
def acquisition(rig):
    return AdaptiveAcquisition(torch.full((3, 32, 32), 0.8), MeanInitializer(), LpdfLighting(),
                               ImageReconstructor(), rig, AcquisitionSettings(lpdf_stride=4))


def test_simulated_acquisition_shows_l0_first_then_the_predicted_patterns(acquisition):
    acq = acquisition.simulate(textured_material(16), method="reference")
    assert acq.patterns.shape == (5, 3, 32, 32) and acq.images.shape == (5, 3, 16, 16)
    assert torch.equal(acq.patterns[0], torch.full((3, 32, 32), 0.8))
    assert torch.allclose(acq.patterns[1, 0], acq.lpdf[0])
    assert acq.svbrdf.resolution == (16, 16) and acq.svbrdf.batch_size == 1


def test_images_are_the_renders_of_the_shown_patterns(acquisition, rig):
    m = textured_material(16)
    acq = acquisition.simulate(m, method="reference")
    again = ms.render(m, acq.patterns, rig)[0]
    assert torch.allclose(acq.images, again, rtol=1e-5, atol=1e-7)


def test_a_batch_gives_one_acquisition_per_material_with_its_own_patterns(acquisition):
    m = ms.SVBRDF.cat([textured_material(16, seed=0, roughness=(0.05, 0.1)),
                       textured_material(16, seed=1, roughness=(0.7, 0.9))])
    a, b = acquisition.simulate(m, method="reference")
    assert not torch.allclose(a.patterns[1:], b.patterns[1:])


def test_mitsuba_simulation_is_reproducible_for_a_seed(acquisition):
    m = textured_material(8)
    a = acquisition.simulate(m, method="mitsuba", spp=2, seed=3)
    b = acquisition.simulate(m, method="mitsuba", spp=2, seed=3)
    assert torch.equal(a.images, b.images)


def test_uniform_lpdf_ablation_ignores_the_initializer(rig):
    p = AdaptiveAcquisition(torch.ones(3, 32, 32), MeanInitializer(), LpdfLighting(), ImageReconstructor(), rig,
                            AcquisitionSettings(lpdf_from="uniform"))
    acq = p.simulate(textured_material(8), method="reference")
    assert torch.equal(acq.lpdf, torch.ones(1, 32, 32))


def test_network_outputs_become_valid_materials():
    raw = torch.randn(2, 10, 4, 4) * 3  # anything a network may emit
    m = maps_to_svbrdf(raw)
    assert (m.normal[:, 2] > 0).all()
    assert torch.allclose(m.normal.norm(dim=1), torch.ones(2, 4, 4), atol=1e-5)


def test_first_pattern_must_fit_the_lcd(rig):
    with pytest.raises(ValueError, match=r"\(3, 32, 32\)"):
        AdaptiveAcquisition(torch.ones(3, 16, 16), MeanInitializer(), LpdfLighting(), ImageReconstructor(), rig)


def test_without_use_spec_g_sc_gets_no_separation(rig):
    rec = ImageReconstructor()
    p = AdaptiveAcquisition(torch.ones(3, 32, 32), MeanInitializer(), LpdfLighting(), rec, rig,
                            AcquisitionSettings(use_spec=False))
    p.simulate(textured_material(8), method="reference")
    assert rec.saw_spec is False


def test_ground_truth_lpdf_needs_the_ground_truth(rig):
    i0 = torch.rand(1, 3, 8, 8)
    with pytest.raises(MitsvbrdfError, match="needs the ground-truth material"):
        predict(MeanInitializer(), LpdfLighting(), i0, rig, AcquisitionSettings(lpdf_from="ground_truth"))


class RatioInitializer(MeanInitializer):
    """MeanInitializer that takes the diffuse-ratio input and keeps the irradiance it was given."""

    diffuse_ratio = True

    def forward(self, i0, irradiance=None):
        self.irradiance = irradiance
        return super().forward(i0)


def test_an_initializer_with_the_diffuse_ratio_input_is_given_l0s_irradiance(rig):
    l0, init = torch.rand(3, 32, 32), RatioInitializer()
    predict(init, LpdfLighting(), torch.rand(1, 3, 16, 16), rig, AcquisitionSettings(), l0=l0)
    assert torch.equal(init.irradiance, diffuse_irradiance(l0[None], rig, 16))


def test_an_initializer_with_the_diffuse_ratio_input_needs_l0(rig):
    with pytest.raises(MitsvbrdfError, match="needs L_0"):
        predict(RatioInitializer(), LpdfLighting(), torch.rand(1, 3, 16, 16), rig, AcquisitionSettings())


def test_an_acquisition_gives_its_initializer_its_own_l0(rig):
    l0, init = torch.rand(3, 32, 32), RatioInitializer()
    AdaptiveAcquisition(l0, init, LpdfLighting(), ImageReconstructor(), rig).predict_patterns(torch.rand(1, 3, 16, 16))
    assert torch.equal(init.irradiance, diffuse_irradiance(l0[None], rig, 16))


@pytest.mark.parametrize("bad", [{"lpdf_from": "oracle"}, {"lpdf_stride": 0}, {"use_spec": "yes"},
                                 {"lpdf_cell_order": 0}, {"lpdf_lobe_grid": -1}, {"lpdf_lobe_grid": 1.5}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(MitsvbrdfError):
        AcquisitionSettings(**bad)


# ---- networks files carry their settings ---------------------------------------------------


def _stage(rig, name="stage2", **model):
    torch.manual_seed(0)
    S = STAGES[name]
    return S(S.Model(**model), S.Loss(), RenderSettings(), rig)


def _save(path, stage, settings="from the stage"):
    recs = {n: network_record(m) for n, m in stage.networks().items()}
    if settings == "from the stage":
        settings = stage.acquisition_settings().record()
    if settings is not None:
        recs[SETTINGS_KEY] = settings
    torch.save(recs, path)
    return path


def test_an_export_is_acquired_with_the_settings_it_was_trained_with(rig, tmp_path):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4, lpdf_from="uniform", lpdf_stride=8, use_spec=False)
    acq = load_adaptive(_save(tmp_path / "n.pt", stage), rig)
    assert acq.settings == AcquisitionSettings("uniform", 8, False)


def test_an_export_carries_its_lpdf_quadrature(rig, tmp_path):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4, lpdf_cell_order=1, lpdf_lobe_grid=16)
    acq = load_adaptive(_save(tmp_path / "n.pt", stage), rig)
    assert acq.settings.lpdf_quadrature == QuadratureSettings(cell_order=1, lobe_grid=16)


def test_predict_computes_lpdf_with_the_settings_quadrature(rig):
    i0 = torch.rand(2, 3, 16, 16)
    coarse = AcquisitionSettings(lpdf_stride=2, lpdf_cell_order=1, lpdf_lobe_grid=4)
    got = predict(MeanInitializer(), LpdfLighting(), i0, rig, coarse).lpdf
    est = maps_to_svbrdf(MeanInitializer()(i0))
    want = importance(est.normal, est.roughness, rig, texel_stride=2, settings=coarse.lpdf_quadrature)
    assert torch.equal(got, want)
    assert not torch.equal(got, predict(MeanInitializer(), LpdfLighting(), i0, rig,
                                        AcquisitionSettings(lpdf_stride=2)).lpdf)


def test_an_export_without_settings_keeps_the_old_defaults(rig, tmp_path):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4, use_spec=False)
    acq = load_adaptive(_save(tmp_path / "old.pt", stage, settings=None), rig)
    assert acq.settings == AcquisitionSettings("initializer", 4, False)  # use_spec as G_sc was built


def test_an_explicit_lpdf_source_overrides_the_file(rig, tmp_path):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4)
    acq = load_adaptive(_save(tmp_path / "n.pt", stage), rig, lpdf_from="uniform")
    assert acq.settings.lpdf_from == "uniform" and acq.settings.lpdf_stride == stage.model_cfg.lpdf_stride


def test_networks_trained_on_the_true_lpdf_acquire_from_the_initializer(rig, tmp_path):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4, lpdf_from="ground_truth")
    assert load_adaptive(_save(tmp_path / "n.pt", stage), rig).settings.lpdf_from == "initializer"


@pytest.mark.parametrize("trained_on, override", [("initializer", "uniform"), ("ground_truth", None)])
def test_a_changed_lpdf_source_keeps_the_other_settings(rig, tmp_path, trained_on, override):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4, lpdf_from=trained_on, lpdf_stride=8,
                   lpdf_cell_order=1, lpdf_lobe_grid=16)
    got = load_adaptive(_save(tmp_path / "n.pt", stage), rig, lpdf_from=override).settings
    assert got.lpdf_from == (override or "initializer")
    assert (got.lpdf_stride, got.lpdf_quadrature) == (8, QuadratureSettings(cell_order=1, lobe_grid=16))


def test_settings_that_contradict_the_networks_are_a_clear_error(rig, tmp_path):
    stage = _stage(rig, lighting_width=4, svbrdf_width=4, use_spec=True)
    path = _save(tmp_path / "n.pt", stage, settings={"use_spec": False})
    with pytest.raises(NetworkFileError, match="built with use_spec=True"):
        load_adaptive(path, rig)


def test_unknown_settings_are_a_clear_error(rig, tmp_path):
    path = _save(tmp_path / "n.pt", _stage(rig, lighting_width=4, svbrdf_width=4), settings={"lpdf_fom": "uniform"})
    with pytest.raises(NetworkFileError, match=r"unknown acquisition settings \['lpdf_fom'\]"):
        load_adaptive(path, rig)


def test_a_baseline_export_is_a_fixed_pattern_acquisition(rig, tmp_path):
    stage = _stage(rig, "fixed", patterns="monograd", svbrdf_width=4)
    acq = load_baseline(_save(tmp_path / "b.pt", stage), rig)
    assert torch.equal(acq.patterns, stage.nets["patterns"]())
    assert acq.simulate(textured_material(8), method="reference").images.shape == (5, 3, 8, 8)


# ---- captures finer than the training grid -------------------------------------------------


class RecordingInitializer(MeanInitializer):
    """MeanInitializer that records the texel grid it was given."""

    def forward(self, i0):
        self.grid = tuple(i0.shape[-2:])
        return super().forward(i0)


class RecordingReconstructor(ImageReconstructor):
    """ImageReconstructor that records every texel grid it was given."""

    def __init__(self):
        super().__init__()
        self.grids = []

    def forward(self, images, spec):
        self.grids.append(tuple(images.shape[-2:]))
        return super().forward(images, spec)


def _trained_at(rig, resolution, transfer):
    init, rec = RecordingInitializer(), RecordingReconstructor()
    acq = AdaptiveAcquisition(torch.full((3, 32, 32), 0.8), init, LpdfLighting(), rec, rig,
                              AcquisitionSettings(resolution=resolution), transfer=transfer)
    return acq, init, rec


def test_networks_trained_on_a_coarser_grid_predict_patterns_from_the_averaged_first_image(rig):
    acq, init, rec = _trained_at(rig, 8, "fused")
    out = acq.simulate(textured_material(16), method="reference")
    assert init.grid == (8, 8)
    assert out.initial.resolution == (16, 16)  # the estimate is upsampled to the capture
    assert rec.grids == [(8, 8)] * (1 + 4) + [(16, 16)] and out.svbrdf.resolution == (16, 16)


def test_native_transfer_runs_every_network_on_the_capture_itself(rig):
    acq, init, rec = _trained_at(rig, 8, "native")
    acq.simulate(textured_material(16), method="reference")
    assert init.grid == (16, 16) and rec.grids == [(16, 16)]


def test_an_export_without_a_training_resolution_reconstructs_on_the_capture_grid(rig):
    acq, init, rec = _trained_at(rig, None, "fused")
    acq.simulate(textured_material(16), method="reference")
    assert init.grid == (16, 16) and rec.grids == [(16, 16)]


def test_a_fixed_pattern_baseline_reconstructs_across_grids_too(rig):
    rec = RecordingReconstructor()
    base = FixedAcquisition(ms.pattern_family("monograd"), rec, rig, use_spec=False, resolution=8, transfer="coarse")
    out = base.simulate(textured_material(16), method="reference")
    assert rec.grids == [(8, 8)] * (1 + 4) and out.svbrdf.resolution == (16, 16)


def test_g_sc_runs_on_one_grid_share_one_irradiance_computation(rig, monkeypatch):
    """The texel-phase runs (resolution.grid_maps) all run on the coarse grid: L^d, which depends
    on the patterns and the grid alone, is computed once per grid, not once per run."""
    import mitsvbrdf.acquisition as acquisition

    grids = []
    monkeypatch.setattr(acquisition, "diffuse_irradiance",
                        lambda p, rig_, grid: grids.append(tuple(grid)) or diffuse_irradiance(p, rig_, grid))
    acq, _, rec = _trained_at(rig, 8, "fused")
    acq.simulate(textured_material(16), method="reference")
    assert len(rec.grids) == 6  # area average + 4 phases on (8, 8), the capture's own run on (16, 16)
    assert sorted(grids) == [(8, 8), (16, 16)]


def test_an_unknown_transfer_mode_is_refused(rig):
    with pytest.raises(MitsvbrdfError, match="transfer must be one of"):
        _trained_at(rig, 8, "tiles")


@pytest.mark.parametrize("bad", [0, 1.5, True, "64"])
def test_a_bad_training_resolution_is_refused(bad):
    with pytest.raises(MitsvbrdfError, match="resolution"):
        AcquisitionSettings(resolution=bad)
