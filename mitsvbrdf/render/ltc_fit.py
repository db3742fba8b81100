"""LTC fit of the project's specular lobe, and the stored table the LTC renderer reads.

The lobe is the cosine-weighted specular BRDF of :mod:`mitsvbrdf.brdf` without Fresnel,
``fcos(w_i) = D G / (4 n.w_o)`` (1/sr), for roughness r and view angle theta_v. A linearly
transformed cosine (Heitz et al. 2016) approximates its shape:

    D_o(w) = D_cos(w') |det M^-1| / |M^-1 w|^3,   w' = M^-1 w / |M^-1 w|,   D_cos = max(0, z) / pi

Frame: +z the shading normal, the view direction ``w_o = (sin theta_v, 0, cos theta_v)`` in the
xz-plane. M^-1 has the 4 free entries of an LTC for a lobe symmetric about the xz-plane,
``[[a, 0, b], [0, c, 0], [d, 0, 1]]`` (the scale of M does not change D_o).

Table: 64 x 64 entries over r_i = i / 63 (alpha = max(r^2, ALPHA_MIN)) and x_j = j / 63 with
cos theta_v = 1 - x_j^2 (dense near normal view, where the lobe changes fastest per degree of
theta_v near 0 for small x; clamped at theta_v = 1.57 rad). Per entry it stores M^-1 and the two
directional albedos of the lobe, A_1 (F = 1) and A_S (F = S, Schlick's weight), so that
``A(ks) = ks (A_1 - A_S) + A_S`` is exact for every F0 = ks.

Fit: per entry, Nelder-Mead on M = R_avg [[a, 0, b], [0, c, 0], [d, 0, 1]] (R_avg turns +z to
the lobe's average direction), minimising the cubic error ``integral |p - D_o|^3`` between the
normalised lobe p = fcos / A_1 and D_o, estimated with a fixed stratified sample set drawn from
both distributions (balance-heuristic weights). The 64 entries of a roughness row are independent
problems, fitted together by a batched Nelder-Mead (:func:`nelder_mead`); each row is warm-started
from the fit of the next rougher row, the first (r = 1) from the cosine itself (M = I), because
the parameters relative to the lobe's average direction change smoothly with roughness. Normal
incidence is fitted isotropic (c = a, b = d = 0).

Lookup (:class:`LtcTable`) interpolates M^-1 and the albedos bilinearly and returns the albedo
scaled by 1 / H, H the LTC's mass above the horizon (closed form), so that a light covering the
whole hemisphere reflects exactly A: the LTC's mass that leaks below the horizon at grazing
views is put back in proportion instead of being lost.

Reproduce the stored table (31 min on one core of a shared 2-core machine):

    python -m mitsvbrdf.render.ltc_fit --out mitsvbrdf/render/ltc_table.npz
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..brdf import roughness_to_alpha, sample_vndf_local, specular_terms, vndf_reflection_pdf

TABLE_PATH = Path(__file__).resolve().parent / "ltc_table.npz"
TABLE_SIZE = 64
#: Largest view angle fitted (radians); the lobe at exactly 90 degrees is degenerate.
MAX_VIEW_ANGLE = 1.57
_F64 = torch.float64


def table_roughness(n: int = TABLE_SIZE) -> np.ndarray:
    """Roughness of the table rows, r_i = i / (n - 1)."""
    return np.arange(n) / (n - 1)


def table_cos_view(n: int = TABLE_SIZE) -> np.ndarray:
    """cos theta_v of the table columns, 1 - x^2 with x = j / (n - 1), clamped at MAX_VIEW_ANGLE."""
    x = np.arange(n) / (n - 1)
    return np.maximum(1.0 - x * x, math.cos(MAX_VIEW_ANGLE))


def stratified_uniforms(n: int, seed: int = 0) -> tuple[Tensor, Tensor]:
    """n x n jittered-stratified points in [0, 1)^2 (float64, flattened), fixed by ``seed``."""
    g = torch.Generator().manual_seed(seed)
    i, j = torch.meshgrid(torch.arange(n, dtype=_F64), torch.arange(n, dtype=_F64), indexing="ij")
    u1 = ((i + torch.rand(n, n, generator=g, dtype=_F64)) / n).reshape(-1)
    u2 = ((j + torch.rand(n, n, generator=g, dtype=_F64)) / n).reshape(-1)
    return u1, u2


class Lobes:
    """E cosine-weighted specular lobes (F = 1) at (roughness (E,), cos theta_v (E,)), view frame.

    Directions are batched as (E, S, 3): S directions per lobe.
    """

    def __init__(self, roughness: Tensor, cos_v: Tensor):
        self.alpha = roughness_to_alpha(roughness.to(_F64))
        self.cos_v = cos_v.to(_F64)
        sin_v = torch.sqrt((1.0 - self.cos_v ** 2).clamp_min(0.0))
        self.wo = torch.stack([sin_v, torch.zeros_like(sin_v), self.cos_v], -1)  # (E, 3)
        self.n = torch.tensor([0.0, 0.0, 1.0], dtype=_F64)

    def _terms(self, wi: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        n = self.n.expand_as(wi)
        f, s, d = specular_terms(n, wi, self.wo[:, None].expand_as(wi), self.alpha[:, None, None])
        return f[..., 0], s[..., 0], d[..., 0]

    def fcos(self, wi: Tensor) -> tuple[Tensor, Tensor]:
        """(fcos, Schlick weight) at directions wi (E, S, 3); fcos in 1/sr, 0 below the horizon."""
        f, s, _ = self._terms(wi)
        return f, s

    def pdf(self, wi: Tensor) -> Tensor:
        """Solid-angle pdf of :meth:`sample` at directions wi (E, S, 3)."""
        _, _, d = self._terms(wi)
        pdf = vndf_reflection_pdf(self.cos_v[:, None], self.alpha[:, None], d)
        return torch.where(wi[..., 2] > 0, pdf, torch.zeros_like(pdf))

    def sample(self, u1: Tensor, u2: Tensor) -> Tensor:
        """Directions (E, S, 3) from the GGX visible-normal distribution, for u1, u2 (S,)."""
        shape = (self.alpha.shape[0], u1.shape[0])
        wo = self.wo[:, None].expand(*shape, 3)
        h = sample_vndf_local(wo, self.alpha[:, None].expand(shape), u1.expand(shape), u2.expand(shape))
        return 2.0 * (wo * h).sum(-1, keepdim=True) * h - wo

    def albedos(self, u1: Tensor, u2: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(A_1 (E,), A_S (E,), unit average direction (E, 3)) by visible-normal sampling."""
        wi = self.sample(u1, u2)
        f, s = self.fcos(wi)
        pdf = self.pdf(wi)
        w = torch.where(pdf > 0, f / pdf.clamp_min(1e-300), torch.zeros_like(f))
        avg = (w[..., None] * wi).sum(1)
        avg[:, 1] = 0.0  # symmetric about the xz-plane
        return w.mean(1), (w * s).mean(1), avg / torch.linalg.vector_norm(avg, dim=-1, keepdim=True)


def ltc_density(m_inv: Tensor, w: Tensor) -> Tensor:
    """D_o(w) for M^-1 (E, 3, 3) at unit directions w (E, S, 3), in 1/sr."""
    wl = torch.einsum("eab,esb->esa", m_inv, w)
    length = torch.linalg.vector_norm(wl, dim=-1)
    cos = (wl[..., 2] / length).clamp_min(0.0)
    return cos / math.pi * torch.linalg.det(m_inv).abs()[:, None] / length ** 3


def rotation_to(avg: Tensor) -> Tensor:
    """Rotations about y taking +z to ``avg`` (E, 3) (unit vectors in the xz-plane); (E, 3, 3)."""
    s, c = avg[:, 0], avg[:, 2]
    z, one = torch.zeros_like(s), torch.ones_like(s)
    return torch.stack([torch.stack([c, z, s], -1), torch.stack([z, one, z], -1),
                        torch.stack([-s, z, c], -1)], -2)


def m_from_params(params: Tensor, rot: Tensor, isotropic: Tensor) -> Tensor:
    """M = R [[a, 0, b], [0, c, 0], [d, 0, 1]] from params (E, 4) = (log a, log c, b, d);
    ``isotropic`` (E,) entries use c = a, b = d = 0 (normal incidence)."""
    iso = isotropic[:, None]
    p = torch.where(iso, torch.stack([params[:, 0], params[:, 0], 0 * params[:, 0], 0 * params[:, 0]], -1), params)
    a, c = torch.exp(p[:, 0]), torch.exp(p[:, 1])
    z, one = torch.zeros_like(a), torch.ones_like(a)
    local = torch.stack([torch.stack([a, z, p[:, 2]], -1), torch.stack([z, c, z], -1),
                         torch.stack([p[:, 3], z, one], -1)], -2)
    return rot @ local


def normalized_inverse(m: Tensor) -> Tensor:
    """M^-1 scaled so that its [2, 2] entry is 1 (the LTC is invariant to the scale of M)."""
    m_inv = torch.linalg.inv(m)
    return m_inv / m_inv[..., 2:3, 2:3]


@dataclass
class FitSamples:
    """The fixed random numbers every error estimate uses (so the fit is deterministic)."""

    u1: Tensor
    u2: Tensor

    @classmethod
    def make(cls, n: int, seed: int) -> "FitSamples":
        return cls(*stratified_uniforms(n, seed))


class FitError:
    """Cubic error integral |p - D_o|^3 dw per lobe (E,), p = fcos / A_1, estimated from equally
    many samples of both densities with balance-heuristic weights. The lobe's own samples do not
    depend on M, so their terms are computed once."""

    def __init__(self, lobes: Lobes, norm: Tensor, samples: FitSamples):
        self.lobes, self.norm, self.samples = lobes, norm, samples
        self.w_lobe = lobes.sample(samples.u1, samples.u2)
        f, _, d = lobes._terms(self.w_lobe)
        self.p_lobe = f / norm[:, None]
        self.pdf_lobe = self._vndf_pdf(d, self.w_lobe)
        r = torch.sqrt(samples.u1)
        phi = 2.0 * math.pi * samples.u2
        self.cosine_dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi),
                                        torch.sqrt((1.0 - samples.u1).clamp_min(0.0))], -1)  # (S, 3)

    def _vndf_pdf(self, d: Tensor, w: Tensor) -> Tensor:
        pdf = vndf_reflection_pdf(self.lobes.cos_v[:, None], self.lobes.alpha[:, None], d)
        return torch.where(w[..., 2] > 0, pdf, torch.zeros_like(pdf))

    def __call__(self, m: Tensor) -> Tensor:
        m_inv = torch.linalg.inv(m)
        det = torch.linalg.det(m_inv).abs()[:, None]
        q_lobe = ltc_density(m_inv, self.w_lobe)
        # The LTC's own samples: D_o(M w_c / |M w_c|) = D_cos(w_c) |det M^-1| |M w_c|^3.
        mw = torch.einsum("eab,sb->esa", m, self.cosine_dirs)
        length = torch.linalg.vector_norm(mw, dim=-1)
        w_ltc = mw / length[..., None]
        q_ltc = self.cosine_dirs[:, 2] / math.pi * det * length ** 3
        f, _, d = self.lobes._terms(w_ltc)
        p_ltc = f / self.norm[:, None]
        total = ((self.p_lobe - q_lobe).abs() ** 3 / (self.pdf_lobe + q_lobe).clamp_min(1e-300)).mean(1)
        total = total + ((p_ltc - q_ltc).abs() ** 3 / (self._vndf_pdf(d, w_ltc) + q_ltc).clamp_min(1e-300)).mean(1)
        return torch.where(torch.isfinite(total), total, torch.full_like(total, 1e300))


def nelder_mead(f, x0: Tensor, steps: Tensor, iterations: int) -> tuple[Tensor, Tensor]:
    """Nelder-Mead (standard coefficients 1, 2, 1/2, 1/2) run on E independent problems at once.

    ``f`` maps (E, k) -> (E,); x0 (E, k) start points, steps (k,) initial simplex edges. Every
    iteration evaluates reflection, expansion and contraction points for all problems (and the
    shrink when any problem needs it), so the batch costs a few evaluations per iteration.
    Returns (best x (E, k), best f (E,)).
    """
    e, k = x0.shape
    simplex = torch.cat([x0[:, None], x0[:, None] + torch.diag(steps)[None]], 1)  # (E, k+1, k)
    fs = torch.stack([f(simplex[:, i]) for i in range(k + 1)], 1)
    rows = torch.arange(e)
    for _ in range(iterations):
        order = fs.argsort(1)
        simplex, fs = simplex[rows[:, None], order], fs.gather(1, order)
        worst, f_worst = simplex[:, -1], fs[:, -1]
        centre = simplex[:, :-1].mean(1)
        xr = 2.0 * centre - worst
        fr = f(xr)
        xe = 3.0 * centre - 2.0 * worst
        fe = f(xe)
        outside = fr < f_worst
        xc = torch.where(outside[:, None], 0.5 * (centre + xr), 0.5 * (centre + worst))
        fc = f(xc)
        best_f, second_worst = fs[:, 0], fs[:, -2]
        expand = (fr < best_f) & (fe < fr)
        reflect = ~expand & (fr < second_worst)
        contract = ~expand & ~reflect & (fc < torch.where(outside, fr, f_worst))
        shrink = ~(expand | reflect | contract)
        new = torch.where(expand[:, None], xe, torch.where(reflect[:, None], xr, xc))
        new_f = torch.where(expand, fe, torch.where(reflect, fr, fc))
        simplex = simplex.clone()
        simplex[:, -1] = torch.where(shrink[:, None], worst, new)
        fs = fs.clone()
        fs[:, -1] = torch.where(shrink, f_worst, new_f)
        if shrink.any():
            shrunk = simplex[:, :1] + 0.5 * (simplex - simplex[:, :1])
            for i in range(1, k + 1):
                fi = f(shrunk[:, i])
                simplex[:, i] = torch.where(shrink[:, None], shrunk[:, i], simplex[:, i])
                fs[:, i] = torch.where(shrink, fi, fs[:, i])
    best = fs.argmin(1)
    return simplex[rows, best], fs[rows, best]


def fit_entries(roughness: Tensor, cos_v: Tensor, start: Tensor, samples: FitSamples,
                albedo_samples: FitSamples, iterations: int = 300) -> dict[str, Tensor]:
    """Fit E table entries at once from warm starts ``start`` (E, 4) = (log a, log c, b, d).

    Returns params (E, 4), m_inv (E, 3, 3) normalised, a_one, a_schlick and the cubic error (E,).
    """
    lobes = Lobes(roughness, cos_v)
    a_one, a_s, avg = lobes.albedos(albedo_samples.u1, albedo_samples.u2)
    isotropic = lobes.cos_v >= 1.0 - 1e-12
    avg = torch.where(isotropic[:, None], lobes.n.expand_as(avg), avg)
    rot = rotation_to(avg)

    error = FitError(lobes, a_one, samples)

    def objective(p: Tensor) -> Tensor:
        return error(m_from_params(p, rot, isotropic))

    steps = torch.tensor([0.1, 0.1, 0.05, 0.05], dtype=_F64)
    params, err = nelder_mead(objective, start.to(_F64), steps, iterations)
    params = torch.where(isotropic[:, None], torch.stack([params[:, 0], params[:, 0], 0 * params[:, 0],
                                                          0 * params[:, 0]], -1), params)
    m = m_from_params(params, rot, isotropic)
    return {"params": params, "m_inv": normalized_inverse(m), "a_one": a_one, "a_schlick": a_s, "error": err}


def fit_table(n: int = TABLE_SIZE, samples: int = 24, albedo_samples: int = 128, iterations: int = 300,
              progress: bool = True) -> dict[str, np.ndarray]:
    """Fit the table row by row from rough to smooth; each row's entries (all view angles) are
    fitted together, warm-started from the next rougher row (the first from the cosine, M = I)."""
    from tqdm import tqdm

    fs, fa = FitSamples.make(samples, seed=0), FitSamples.make(albedo_samples, seed=1)
    rough = torch.from_numpy(table_roughness(n))
    cos_v = torch.from_numpy(table_cos_view(n))
    keys = ("params", "a_one", "a_schlick", "error")
    out = {k: [None] * n for k in keys + ("m_inv",)}
    start = torch.zeros(n, 4, dtype=_F64)  # M = identity: the cosine lobe, close for r = 1
    for i in tqdm(range(n - 1, -1, -1), desc="LTC fit (rows)", disable=not progress):
        e = fit_entries(rough[i].expand(n), cos_v, start, fs, fa, iterations)
        for k in keys:
            out[k][i] = e[k].numpy()
        out["m_inv"][i] = e["m_inv"][:, [0, 0, 1, 2], [0, 2, 1, 0]].numpy()
        start = e["params"]
    table = {k: np.stack(v) for k, v in out.items()}
    table["roughness"], table["cos_view"] = rough.numpy(), cos_v.numpy()
    table["settings"] = np.array([samples, albedo_samples, iterations])  # how to refit an entry
    return table


def m_inv_from_entries(e: Tensor) -> Tensor:
    """(..., 4) stored entries (a, b, c, d) -> (..., 3, 3) M^-1 = [[a, 0, b], [0, c, 0], [d, 0, 1]]."""
    z, one = torch.zeros_like(e[..., 0]), torch.ones_like(e[..., 0])
    rows = [torch.stack([e[..., 0], z, e[..., 1]], -1), torch.stack([z, e[..., 2], z], -1),
            torch.stack([e[..., 3], z, one], -1)]
    return torch.stack(rows, -2)


def hemisphere_mass(m_inv: Tensor) -> Tensor:
    """Mass of the LTC above the horizon, (1 + cos phi) / 2 with phi the tilt of the plane that
    M^-1 maps the horizon to: (..., 3, 3) -> (...). For the table's form [[a, 0, b], [0, c, 0],
    [d, 0, 1]] the z row of M is (-d, 0, a) / (a - b d), so cos phi = sign(a - b d) a / |(d, a)|
    (closed form: a batched 3x3 inverse cost more than the rest of a lookup)."""
    a, b, d = m_inv[..., 0, 0], m_inv[..., 0, 2], m_inv[..., 2, 0]
    return 0.5 * (1.0 + torch.sign(a - b * d) * a * torch.rsqrt((a * a + d * d).clamp_min(1e-24)))


class LtcTable:
    """The fitted table with the lookup the LTC renderer uses.

    ``lookup(roughness (N,), cos_theta_v (N,))`` -> ``(m_inv (N, 3, 3), a_one (N,), a_schlick (N,))``
    in the view frame of :func:`mitsvbrdf.render.ltc.view_frame`, bilinear in (r, sqrt(1 - cos)),
    differentiable in both; albedos already divided by the hemisphere mass (module docstring).
    """

    def __init__(self, data: dict[str, np.ndarray]):
        for key in ("m_inv", "a_one", "a_schlick"):
            if key not in data:
                raise ValueError(f"LTC table lacks {key!r}")
        self.size = data["a_one"].shape[0]
        grid = np.concatenate([data["m_inv"], data["a_one"][..., None], data["a_schlick"][..., None]], -1)
        self.grid = torch.from_numpy(grid.astype(np.float32))  # (n_r, n_v, 6)
        self.error = data.get("error")

    @classmethod
    def load(cls, path: str | Path = TABLE_PATH) -> "LtcTable":
        with np.load(path) as f:
            return cls({k: f[k] for k in f.files})

    def lookup(self, roughness: Tensor, cos_v: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        n = self.size - 1
        grid = self.grid.to(roughness.device, roughness.dtype)
        fr = roughness.clamp(0.0, 1.0) * n
        x = torch.sqrt((1.0 - cos_v.clamp(0.0, 1.0)).clamp_min(0.0) + 1e-12)
        x = x.clamp(max=math.sqrt(1.0 - math.cos(MAX_VIEW_ANGLE)))
        fv = x * n
        i0 = fr.detach().floor().clamp(0, n - 1).long()
        j0 = fv.detach().floor().clamp(0, n - 1).long()
        tr, tv = (fr - i0)[:, None], (fv - j0)[:, None]
        v = (grid[i0, j0] * (1 - tr) * (1 - tv) + grid[i0 + 1, j0] * tr * (1 - tv)
             + grid[i0, j0 + 1] * (1 - tr) * tv + grid[i0 + 1, j0 + 1] * tr * tv)
        m_inv = m_inv_from_entries(v[:, :4])
        mass = hemisphere_mass(m_inv).clamp_min(1e-3)
        return m_inv, v[:, 4] / mass, v[:, 5] / mass


@lru_cache(maxsize=None)
def default_table() -> LtcTable:
    """The table shipped with the package (fitted by this module's ``main``)."""
    if not TABLE_PATH.exists():
        raise FileNotFoundError(f"{TABLE_PATH} is missing; fit it with "
                                f"`python -m mitsvbrdf.render.ltc_fit --out {TABLE_PATH}`")
    return LtcTable.load(TABLE_PATH)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Fit the LTC table of the project's specular lobe.")
    ap.add_argument("--out", type=Path, required=True, help="output .npz")
    ap.add_argument("--size", type=int, default=TABLE_SIZE, help="entries per axis (default 64)")
    ap.add_argument("--samples", type=int, default=24, help="n for n x n fit samples per density")
    ap.add_argument("--albedo-samples", type=int, default=128, help="n for n x n albedo samples")
    ap.add_argument("--iterations", type=int, default=300, help="Nelder-Mead iterations per row")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    table = fit_table(args.size, args.samples, args.albedo_samples, args.iterations)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **{k: (v.astype(np.float32) if k not in ("params", "settings") else v)
                                     for k, v in table.items()})
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB) in {time.perf_counter() - t0:.0f} s; "
          f"cubic fit error median {np.median(table['error']):.3g}, max {table['error'].max():.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
