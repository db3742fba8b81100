"""The project's one BRDF: the Deschaintre et al. 2018 "Substance" GGX model (docs/conventions.md).

    alpha = max(r^2, ALPHA_MIN)
    D     = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)
    G     = G1(n.l) G1(n.v),   G1(c) = c / (c (1 - k) + k),   k = alpha / 2
    F     = ks + (1 - ks) S,   S = 2^((-5.55473 (v.h) - 6.98316) (v.h))
    f     = kd (1 - ks) / pi + D G F / (4 (n.l)(n.v))

Conventions: all direction vectors are unit vectors pointing *away* from the surface point
(``wi`` towards the light, ``wo`` towards the camera) in any common frame; their xyz components
lie along dimension ``dim`` (default last). Colour parameters (kd, ks) carry RGB along the same
dimension, roughness a single channel there, so the functions broadcast over any batch layout:
``(N, 3)`` point lists with ``dim=-1`` or ``(B, 3, H, W)`` images with ``dim=-3``.

Numerics: the function is written so that it stays finite at the extremes. D uses
``alpha^2 cos^2 + sin^2`` with ``sin^2 = |n x h|^2`` (no cancellation near the mirror direction),
the G/(4 n.l n.v) quotient is simplified analytically to ``1 / (4 (n.l(1-k)+k)(n.v(1-k)+k))``
(finite at grazing angles), and the BRDF is exactly zero, with zero gradient, when the light or
the view is below the shading normal's horizon. Roughness below ``sqrt(ALPHA_MIN)`` behaves as
``ALPHA_MIN``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

#: Smallest GGX alpha (= roughness^2). r = 0.01 maps to it exactly; smaller r is clamped.
ALPHA_MIN = 1e-4

_LOBES = ("both", "diffuse", "specular")


def roughness_to_alpha(roughness: Tensor) -> Tensor:
    """GGX alpha = r^2, clamped to ``ALPHA_MIN`` (never 0)."""
    return (roughness * roughness).clamp_min(ALPHA_MIN)


def _dot(a: Tensor, b: Tensor, dim: int) -> Tensor:
    return (a * b).sum(dim=dim, keepdim=True)


def _normalize(v: Tensor, dim: int) -> Tensor:
    return v / torch.linalg.vector_norm(v, dim=dim, keepdim=True).clamp_min(1e-12)


def ggx_ndf(alpha: Tensor, cos_h: Tensor, sin2_h: Tensor) -> Tensor:
    """GGX normal distribution D(h) in 1/sr, from cos and sin^2 of the half-vector angle.

    Passing ``sin2_h`` separately (e.g. ``|n x h|^2``) keeps D accurate for tiny alpha where
    ``1 - cos^2`` cancels in float32. D is 0 for back-facing microfacets (cos_h <= 0).
    """
    a2 = alpha * alpha
    denom = a2 * cos_h * cos_h + sin2_h
    d = a2 / (math.pi * (denom * denom).clamp_min(1e-30))
    return torch.where(cos_h > 0, d, torch.zeros_like(d))


def schlick_weight(v_dot_h: Tensor) -> Tensor:
    """The spherical-Gaussian Schlick factor S = 2^((-5.55473 c - 6.98316) c), in (0, 1]."""
    c = v_dot_h.clamp(0.0, 1.0)
    return torch.exp2((-5.55473 * c - 6.98316) * c)


def fresnel(ks: Tensor, v_dot_h: Tensor) -> Tensor:
    """F = ks + (1 - ks) S(v.h), broadcast over RGB."""
    s = schlick_weight(v_dot_h)
    return ks + (1.0 - ks) * s


def smith_schlick_g1(cos: Tensor, alpha: Tensor) -> Tensor:
    """Schlick-Smith masking G1(c) = c / (c (1 - k) + k), k = alpha / 2; 0 for c <= 0."""
    k = 0.5 * alpha
    c = cos.clamp_min(0.0)
    return c / (c * (1.0 - k) + k)


def smith_ggx_g1(cos: Tensor, alpha: Tensor) -> Tensor:
    """Exact Smith G1 of GGX, 2 / (1 + sqrt(1 + alpha^2 tan^2)); the VNDF's normaliser."""
    c2 = cos.clamp(1e-12, 1.0) ** 2
    tan2 = (1.0 - c2) / c2
    return 2.0 / (1.0 + torch.sqrt(1.0 + alpha * alpha * tan2))


def specular_terms(
    n: Tensor, wi: Tensor, wo: Tensor, alpha: Tensor, dim: int = -1
) -> tuple[Tensor, Tensor, Tensor]:
    """Pieces of the specular lobe shared by renderers: ``(fcos, schlick, d)``.

    ``fcos = D G / (4 (n.l)(n.v)) * (n.l)`` without Fresnel, so that the cosine-weighted specular
    BRDF is ``fcos * (ks (1 - schlick) + schlick)``: linear in ks, which lets renderers integrate
    two ks-independent kernels once and apply any ks afterwards. ``d`` is D(h). All three carry a
    singleton channel along ``dim``; zero where either direction is below the horizon.
    """
    nl = _dot(n, wi, dim)
    nv = _dot(n, wo, dim)
    h = _normalize(wi + wo, dim)
    cos_h = _dot(n, h, dim)
    sin2_h = torch.linalg.vector_norm(torch.linalg.cross(*torch.broadcast_tensors(n, h), dim=dim),
                                      dim=dim, keepdim=True) ** 2
    d = ggx_ndf(alpha, cos_h, sin2_h)
    k = 0.5 * alpha
    nl_c = nl.clamp_min(0.0)
    nv_c = nv.clamp_min(0.0)
    fcos = d * nl_c / (4.0 * (nl_c * (1.0 - k) + k) * (nv_c * (1.0 - k) + k))
    visible = (nl > 0) & (nv > 0)
    fcos = torch.where(visible, fcos, torch.zeros_like(fcos))
    return fcos, schlick_weight(_dot(wo, h, dim)), d


def brdf(
    n: Tensor,
    wi: Tensor,
    wo: Tensor,
    diffuse: Tensor,
    specular: Tensor,
    roughness: Tensor,
    *,
    lobes: str = "both",
    cosine: bool = False,
    dim: int = -1,
) -> Tensor:
    """Evaluate f(wi, wo) (1/sr, RGB), or f * (n.wi)^+ with ``cosine=True``.

    Args:
        n, wi, wo: unit vectors (shading normal, light and view directions), xyz along ``dim``.
        diffuse, specular: kd and ks albedos in [0, 1], RGB along ``dim``.
        roughness: r in [0, 1], one channel along ``dim``; alpha = max(r^2, ALPHA_MIN).
        lobes: "both", "diffuse" (kd (1 - ks) / pi only) or "specular" (D G F / (4 n.l n.v) only).
        cosine: multiply by the clamped cosine (n.wi)^+ (the rendering integrand).
    Returns:
        RGB values broadcast from the inputs; exactly 0 where n.wi <= 0 or n.wo <= 0.
    """
    if lobes not in _LOBES:
        raise ValueError(f"lobes must be one of {_LOBES}, got {lobes!r}")
    nl = _dot(n, wi, dim)
    nv = _dot(n, wo, dim)
    visible = (nl > 0) & (nv > 0)
    # f * cos for the specular part is finite at n.l = 0; divide the cosine back out safely.
    cos_out = nl.clamp_min(0.0) if cosine else torch.ones_like(nl)
    out = torch.zeros_like(diffuse * specular * nl)
    if lobes in ("both", "diffuse"):
        fd = diffuse * (1.0 - specular) / math.pi
        out = out + torch.where(visible, fd * cos_out, torch.zeros_like(out))
    if lobes in ("both", "specular"):
        alpha = roughness_to_alpha(roughness)
        fcos, s, _ = specular_terms(n, wi, wo, alpha, dim)
        if cosine:
            spec = fcos
        else:
            spec = torch.where(visible, fcos / nl.clamp_min(1e-12), torch.zeros_like(fcos))
        out = out + spec * (specular * (1.0 - s) + s)
    return out


# --- visible-normal sampling (Dupuy & Benyoub 2023, spherical caps) ---------------------------


def sample_vndf_local(wo: Tensor, alpha: Tensor, u1: Tensor, u2: Tensor) -> Tensor:
    """Sample a GGX visible normal h in the local frame (normal = +z), xyz in the last dim.

    ``wo`` (..., 3) must have wo.z > 0; ``alpha`` broadcastable to wo[..., 0]; u1, u2 in [0, 1).
    The density of h is ``G1_smith(wo) max(0, wo.h) D(h) / wo.z``.
    """
    a = alpha.unsqueeze(-1)
    wstd = torch.cat([wo[..., :2] * a, wo[..., 2:]], dim=-1)
    wstd = _normalize(wstd, -1)
    phi = 2.0 * math.pi * u1
    z = (1.0 - u2) * (1.0 + wstd[..., 2]) - wstd[..., 2]
    # sqrt has an infinite derivative at 0 (z = +-1, the cap's poles, e.g. u2 = 0): clamping its
    # argument just above 0 keeps the gradient finite and moves h by at most 1e-15.
    sin_t = torch.sqrt(((1.0 - z) * (1.0 + z)).clamp_min(1e-30))
    cap = torch.stack([sin_t * torch.cos(phi), sin_t * torch.sin(phi), z], dim=-1)
    hstd = cap + wstd
    h = torch.cat([hstd[..., :2] * a, hstd[..., 2:].clamp_min(0.0)], dim=-1)
    return _normalize(h, -1)


def vndf_reflection_pdf(cos_o: Tensor, alpha: Tensor, d: Tensor) -> Tensor:
    """Solid-angle pdf of wi = reflect(wo, h) for h sampled from the VNDF.

    ``pdf(wi) = G1_smith(wo) D(h) / (4 n.wo)``; 0 where n.wo <= 0.
    """
    pdf = smith_ggx_g1(cos_o, alpha) * d / (4.0 * cos_o.clamp_min(1e-12))
    return torch.where(cos_o > 0, pdf, torch.zeros_like(pdf))


def tangent_frame(n: Tensor) -> tuple[Tensor, Tensor]:
    """Orthonormal tangents (t, b) for unit normals n (..., 3), branchless (Duff et al. 2017)."""
    sign = torch.where(n[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    t = torch.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], dim=-1)
    bt = torch.stack([b, sign + n[..., 1] ** 2 * a, -n[..., 1]], dim=-1)
    return t, bt
