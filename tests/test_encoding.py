"""The albedo-encoding check of dataset strips (mitsvbrdf.data.encoding): the flash geometry, and that
a render tile tells the encoding it was rendered with."""

from __future__ import annotations

import math

import pytest
import torch

import mitsvbrdf as ms
from mitsvbrdf.data import encoding
from mitsvbrdf.viewing import tonemap


def _material(size: int = 24) -> ms.SVBRDF:
    """Diffuse albedo from dark to bright across the sample (coloured), dielectric ks, mild bumps."""
    y, x = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    kd = torch.stack([0.05 + 0.6 * x, 0.04 + 0.4 * y, 0.03 + 0.2 * x * y])
    n = torch.stack([0.15 * torch.sin(6 * x), 0.15 * torch.cos(5 * y), torch.ones_like(x)])
    n = n / n.norm(dim=0, keepdim=True)
    return ms.SVBRDF(normal=n, diffuse=kd, roughness=torch.full((1, size, size), 0.45),
                     specular=torch.full((3, size, size), 0.04))


def test_flash_image_is_brightest_under_the_flash_with_y_up():
    m = ms.SVBRDF.constant(diffuse=0.2, specular=0.5, roughness=0.15, size=33)
    img = encoding.flash_image(m, torch.tensor([0.5, 0.5, 1.5]))[0].sum(0)
    row, col = divmod(int(img.argmax()), 33)
    # x = 0.5 is column (0.5 + 1) / 2 * 33 - 0.5 = 24.25; y = +0.5 (up) is row (1 - 0.5) / 2 * 33 - 0.5 = 7.75
    assert abs(col - 24.25) <= 1 and abs(row - 7.75) <= 1


def test_srgb_hypothesis_renders_the_decoded_albedos():
    m = ms.SVBRDF.constant(diffuse=0.5, specular=0.04, roughness=0.5, size=4)
    dec = ms.SVBRDF.constant(diffuse=float(ms.svbrdf.srgb_to_linear(torch.tensor(0.5))),
                             specular=float(ms.svbrdf.srgb_to_linear(torch.tensor(0.04))), roughness=0.5, size=4)
    p = torch.tensor([0.0, 0.0, 2.0])
    torch.testing.assert_close(encoding.flash_image(m, p, "srgb"), encoding.flash_image(dec, p, "linear"))


@pytest.mark.parametrize("truth", encoding.HYPOTHESES)
def test_a_tile_rendered_with_one_encoding_is_matched_best_by_it(truth):
    """An 8-bit tile rendered under ``truth`` (flash off-centre, unknown scale) is fitted to its
    quantisation level (1 / (255 sqrt 12) = 0.0011 RMSE; allowed 0.005 for the fit), the other
    hypotheses at least twice as badly."""
    m = _material()
    tile = tonemap(encoding.flash_image(m, torch.tensor([0.2, -0.1, 1.8]), truth) * 3.0, exposure=1.0)
    tile = (tile * 255).round() / 255
    res = encoding.compare_encodings(m, tile, fit_size=24, steps=150, starts=encoding.STARTS[:2])
    assert res[truth]["rmse"] < 0.005
    for other in set(encoding.HYPOTHESES) - {truth}:
        assert res[other]["rmse"] > 2 * res[truth]["rmse"], other
    assert math.dist(res[truth]["position"], [0.2, -0.1, 1.8]) < 0.1
