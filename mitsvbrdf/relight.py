"""Re-rendering of materials under novel lighting, for evaluation and reports.

Two kinds of novel lighting, both seen from the rig's camera on the sample's texel grid (like the
capture images):

* isotropic point lights above the sample: ``L_o = f(w_i, w_o) (n . w_i)^+ I / d^2`` at every texel
  (exact, no sampling: one light direction per texel), ``I`` the intensity in W/sr (relative);
* LCD patterns (e.g. step edges, :func:`mitsvbrdf.patterns.step_edges`) through any renderer.

:class:`FlashLight` is the point light at the camera of the flash baseline.

Images are linear radiance (B, L, 3, H, W); :func:`mitsvbrdf.viewing.tonemap` maps them to display
values for metrics that want a perceptual scale (SSIM) and for pictures.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .brdf import brdf
from .rig import Rig


def random_point_lights(n: int = 10, seed: int = 0, *, distance: tuple[float, float] = (0.15, 0.4),
                        min_elevation_deg: float = 25.0) -> Tensor:
    """(n, 3) point-light positions in metres above the sample centre, seeded.

    Directions are uniform in solid angle above ``min_elevation_deg``; distances uniform in
    ``distance`` (metres), so the lights sit well outside the 6 cm sample and above its horizon.
    """
    if n < 1:
        raise ValueError(f"need at least one light, got n={n}")
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 3, generator=g, dtype=torch.float64)
    z_min = math.sin(math.radians(min_elevation_deg))
    z = z_min + (1.0 - z_min) * u[:, 0]
    phi = 2.0 * math.pi * u[:, 1]
    s = torch.sqrt(1.0 - z * z)
    d = distance[0] + (distance[1] - distance[0]) * u[:, 2]
    return (torch.stack([s * torch.cos(phi), s * torch.sin(phi), z], -1) * d[:, None]).float()


def point_light_images(svbrdf, lights: Tensor, rig: Rig, intensity: float = 0.01) -> Tensor:
    """Render B materials under each of L point lights (L, 3) (metres): (B, L, 3, H, W).

    ``intensity`` in W/sr (relative units; 0.01 W/sr at 20 cm gives about the irradiance of the
    LCD at full drive). Differentiable w.r.t. the maps.
    """
    h, w = svbrdf.resolution
    dev, dt = svbrdf.normal.device, svbrdf.normal.dtype
    x = rig.surface_points((h, w), dev).to(dt).permute(2, 0, 1)  # (3, H, W)
    wo = rig.view_directions((h, w), dev).to(dt).permute(2, 0, 1)
    out = []
    for p in lights.to(dev, dt):
        d = p.view(3, 1, 1) - x
        dist2 = (d * d).sum(0, keepdim=True)
        wi = d / dist2.sqrt()
        f = brdf(svbrdf.normal, wi[None], wo[None], svbrdf.diffuse, svbrdf.specular, svbrdf.roughness,
                 cosine=True, dim=-3)
        out.append(f * (intensity / dist2)[None])
    return torch.stack(out, 1)


class FlashLight(torch.nn.Module):
    """A point light co-located with the camera (a flash): the light source of the flash baseline.

    ``forward(svbrdf, rig)`` -> (B, 1, 3, H, W) linear radiance, rendered exactly by
    :func:`point_light_images` from the rig's camera centre. ``intensity`` in W/sr: the default
    0.04 W/sr at the default rig's 0.40 m camera distance gives about the irradiance of the LCD at
    full drive. It has no parameters; it is a module so that a baseline's network file records it.
    """

    def __init__(self, intensity: float = 0.04):
        super().__init__()
        if not intensity > 0:
            raise ValueError(f"flash intensity must be positive, got {intensity}")
        self.config = dict(intensity=float(intensity))

    def forward(self, svbrdf, rig: Rig) -> Tensor:
        return point_light_images(svbrdf, rig.camera_position[None], rig, intensity=self.config["intensity"])
