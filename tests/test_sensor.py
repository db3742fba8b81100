"""Sensor noise on rendered images."""

import pytest
import torch

from mitsvbrdf.sensor import SensorNoise


def test_shot_and_read_noise_have_the_modelled_variance():
    x = torch.full((200_000,), 0.25)
    y = SensorNoise(shot=0.01, read=0.02)(x, torch.Generator().manual_seed(0))
    assert float(y.mean()) == pytest.approx(0.25, abs=1e-3)
    assert float(y.var()) == pytest.approx(0.01 * 0.25 + 0.02 ** 2, rel=0.02)


def test_quantisation_gives_the_levels_of_the_bit_depth():
    y = SensorNoise(bits=8)(torch.rand(10_000))
    assert torch.allclose(y * 255, torch.round(y * 255), atol=1e-4)


def test_saturation_clips_at_the_white_level():
    y = SensorNoise(read=0.01, white=2.0)(torch.full((1000,), 5.0), torch.Generator().manual_seed(1))
    assert float(y.max()) == 2.0


def test_seeded_noise_is_reproducible():
    x = torch.rand(100)
    n = SensorNoise(shot=0.01, read=0.01, bits=12)
    assert torch.equal(n(x, torch.Generator().manual_seed(3)), n(x, torch.Generator().manual_seed(3)))


def test_gradients_pass_through():
    x = torch.rand(100, requires_grad=True)
    SensorNoise(shot=0.01, read=0.01, bits=8)(x, torch.Generator().manual_seed(0)).sum().backward()
    assert torch.allclose(x.grad, torch.ones(100))


def test_negative_settings_are_refused():
    with pytest.raises(ValueError):
        SensorNoise(shot=-1.0)
