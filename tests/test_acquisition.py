"""The acquisition pipeline around injected networks (tiny stand-ins here; trained nets elsewhere)."""

from types import SimpleNamespace

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.pipeline import AcquisitionPipeline, maps_to_svbrdf

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
    def forward(self, images, spec):
        b, _, _, h, w = images.shape
        out = torch.full((b, 10, h, w), 0.5)
        out[:, 3:6] = (images[:, 0] / images[:, 0].amax((1, 2, 3), keepdim=True)).clamp(0, 1)
        return out


@pytest.fixture()
def pipeline(rig):
    return AcquisitionPipeline(torch.full((3, 32, 32), 0.8), MeanInitializer(), LpdfLighting(),
                               ImageReconstructor(), rig, lpdf_stride=4)


def test_simulated_acquisition_shows_l0_first_then_the_predicted_patterns(pipeline):
    acq = pipeline.simulate(textured_material(16), method="reference")
    assert acq.patterns.shape == (5, 3, 32, 32) and acq.images.shape == (5, 3, 16, 16)
    assert torch.equal(acq.patterns[0], torch.full((3, 32, 32), 0.8))
    assert torch.allclose(acq.patterns[1, 0], acq.lpdf[0])
    assert acq.svbrdf.resolution == (16, 16) and acq.svbrdf.batch_size == 1


def test_images_are_the_renders_of_the_shown_patterns(pipeline, rig):
    m = textured_material(16)
    acq = pipeline.simulate(m, method="reference")
    again = ms.render(m, acq.patterns, rig)[0]
    assert torch.allclose(acq.images, again, rtol=1e-5, atol=1e-7)


def test_a_batch_gives_one_acquisition_per_material_with_its_own_patterns(pipeline):
    m = ms.SVBRDF.cat([textured_material(16, seed=0, roughness=(0.05, 0.1)),
                       textured_material(16, seed=1, roughness=(0.7, 0.9))])
    a, b = pipeline.simulate(m, method="reference")
    assert not torch.allclose(a.patterns[1:], b.patterns[1:])


def test_mitsuba_simulation_is_reproducible_for_a_seed(pipeline):
    m = textured_material(8)
    a = pipeline.simulate(m, method="mitsuba", spp=2, seed=3)
    b = pipeline.simulate(m, method="mitsuba", spp=2, seed=3)
    assert torch.equal(a.images, b.images)


def test_uniform_lpdf_ablation_ignores_the_initializer(rig):
    p = AcquisitionPipeline(torch.ones(3, 32, 32), MeanInitializer(), LpdfLighting(), ImageReconstructor(), rig,
                            lpdf_from="uniform")
    acq = p.simulate(textured_material(8), method="reference")
    assert torch.equal(acq.lpdf, torch.ones(1, 32, 32))


def test_network_outputs_become_valid_materials():
    raw = torch.randn(2, 10, 4, 4) * 3  # anything a network may emit
    m = maps_to_svbrdf(raw)
    assert (m.normal[:, 2] > 0).all()
    assert torch.allclose(m.normal.norm(dim=1), torch.ones(2, 4, 4), atol=1e-5)


def test_first_pattern_must_fit_the_lcd(rig):
    with pytest.raises(ValueError, match=r"\(3, 32, 32\)"):
        AcquisitionPipeline(torch.ones(3, 16, 16), MeanInitializer(), LpdfLighting(), ImageReconstructor(), rig)
