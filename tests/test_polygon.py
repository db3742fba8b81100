"""Closed-form clipped polygon integrals (the basis of the LTC renderer)."""

import math

import pytest
import torch

from mitsvbrdf.render.polygon import clipped_polygon_form_factor, grid_cell_form_factors, lcd_cell_form_factors
from mitsvbrdf.render.quadrature import QuadratureSettings, cell_kernels
from mitsvbrdf.render.reference import diffuse_integrand


def _dense_form_factor(poly, n=1500):
    """(1/pi) * integral of (z . w)^+ over a planar parallelogram by a dense midpoint rule (float64)."""
    g = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    v, u = torch.meshgrid(g, g, indexing="ij")
    e1, e2 = poly[1] - poly[0], poly[3] - poly[0]
    p = poly[0] + u[..., None] * e1 + v[..., None] * e2
    normal = torch.linalg.cross(e1, e2)
    area = normal.norm()
    d2 = (p * p).sum(-1)
    w = p / d2.sqrt()[..., None]
    return ((w[..., 2].clamp_min(0) * (w @ (normal / area)).abs()) / d2).sum() * area / n / n / math.pi


@pytest.mark.parametrize("poly", [
    [[-0.3, -0.2, 0.5], [0.4, -0.2, 0.6], [0.4, 0.5, 0.7], [-0.3, 0.5, 0.6]],   # above the horizon
    [[-0.5, -0.2, -0.3], [0.4, -0.2, 0.3], [0.4, 0.5, 0.4], [-0.5, 0.5, -0.2]],  # crosses it
])
def test_form_factor_matches_dense_integration_in_both_orientations(poly):
    p = torch.tensor(poly, dtype=torch.float64)
    want = _dense_form_factor(p).item()
    assert abs(clipped_polygon_form_factor(p).item() - want) < 1e-6
    assert abs(clipped_polygon_form_factor(p.flip(0)).item() - want) < 1e-6


def test_grid_cells_sharing_their_edges_have_each_cells_own_form_factor():
    """A 3 x 4 grid of quads above the horizon (one skewed corner, so the quads differ): each
    quad's value is its own polygon's form factor, in float64 rounding."""
    v, u = torch.meshgrid(torch.linspace(-0.4, 0.3, 4, dtype=torch.float64),
                          torch.linspace(-0.5, 0.6, 5, dtype=torch.float64), indexing="ij")
    corners = torch.stack([u, v, 0.5 + 0.2 * u - 0.1 * v], -1)
    corners[1, 2] += torch.tensor([0.05, -0.03, 0.04], dtype=torch.float64)
    quads = torch.stack([corners[:-1, :-1], corners[:-1, 1:], corners[1:, 1:], corners[1:, :-1]], -2)
    torch.testing.assert_close(grid_cell_form_factors(corners), clipped_polygon_form_factor(quads),
                               rtol=1e-12, atol=1e-15)


def test_polygon_below_the_horizon_contributes_nothing():
    p = torch.tensor([[-0.3, -0.2, -0.5], [0.4, -0.2, -0.6], [0.4, 0.5, -0.7], [-0.3, 0.5, -0.6]])
    assert clipped_polygon_form_factor(p).item() == 0.0


def test_huge_polygon_covers_the_hemisphere():
    p = torch.tensor([[-1e4, -1e4, 1.0], [1e4, -1e4, 1.0], [1e4, 1e4, 1.0], [-1e4, 1e4, 1.0]], dtype=torch.float64)
    assert abs(clipped_polygon_form_factor(p).item() - 1.0) < 1e-6


def test_gradients_are_finite_for_tiny_and_grazing_polygons():
    p = torch.tensor([[[0.0, 0.0, 1.0], [1e-7, 0.0, 1.0], [1e-7, 1e-7, 1.0], [0.0, 1e-7, 1.0]],
                      [[-0.5, -0.2, 0.0], [0.4, -0.2, 1e-9], [0.4, 0.5, 0.2], [-0.5, 0.5, 0.0]]], requires_grad=True)
    clipped_polygon_form_factor(p).sum().backward()
    assert torch.isfinite(p.grad).all()


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (0.35, -0.2, 1.0), (-0.9, 0.1, 0.45)])
def test_cell_form_factors_equal_the_reference_diffuse_kernel(rig, normal):
    """Exact polygon integrals vs. the reference quadrature (dense, so its own error is tiny);
    the last normal puts the horizon through the LCD."""
    x = rig.surface_points(3).reshape(-1, 3).double()
    wo = rig.view_directions(3).reshape(-1, 3).double()
    n = torch.nn.functional.normalize(torch.tensor(normal, dtype=torch.float64), dim=0).expand_as(x).contiguous()
    corners = rig.lcd_cell_corners().reshape(-1, 4, 3).double()
    exact = lcd_cell_form_factors(x, n, wo, corners)
    lcd = rig.lcd_geometry(dtype=torch.float64)
    quad = cell_kernels(x, n, wo, torch.ones(x.shape[0], dtype=torch.float64), lcd, diffuse_integrand,
                        QuadratureSettings(cell_order=12, lobe_grid=0))[:, 0]
    assert (exact - quad).abs().max() < 1e-4 * exact.sum(1).max()
    assert (exact.sum(1) - quad.sum(1)).abs().max() < 1e-5
