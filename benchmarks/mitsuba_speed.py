"""Mitsuba renderer: forward and forward+backward time, and error against the reference.

    .venv/bin/python benchmarks/mitsuba_speed.py             # CPU (llvm); CUDA too when available
    .venv/bin/python benchmarks/mitsuba_speed.py --quick     # 64 px smoke run

For each estimator of the ``importance`` integrator (``--estimators``, see benchmarks/estimators.py),
B in {1, 8} materials x P = 5 MonoGrad patterns at 256 x 256 and spp in {1, 4, 16, 64}: the wall
time of a forward render of new materials (no control-variate terms of the same maps at hand), of
a second forward render of the same materials (a training step and an acquisition render each
batch twice, I_0 and then the adaptive patterns, and the second reuses the terms that depend on
the maps alone) and of forward + backward (gradients w.r.t. patterns and all maps), each the
fastest of ``--repeats`` after one warm-up call that compiles the kernels (other work on a shared
machine only adds time). The error column is the relative RMSE of the B = 1 render against the
reference renderer (material 0, default quadrature). Writes docs/benchmarks/mitsuba_speed_<device>.md
and .csv.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.patterns import monograd
from mitsvbrdf.render.control_variate import LAST_MATERIALS
from estimators import DEFAULT, estimator_rigs
from report import OtherLoad, write_report

ROOT = Path(__file__).resolve().parent.parent


def materials(b: int, size: int, device) -> ms.SVBRDF:
    """Seeded bumpy materials spanning roughness 0.05..0.8 (no file I/O: runs anywhere)."""
    g = torch.Generator().manual_seed(0)
    n = torch.randn(b, 3, size // 8, size // 8, generator=g) * 0.3
    n = torch.nn.functional.interpolate(n, size=(size, size), mode="bilinear", align_corners=False)
    n[:, 2] = 1.0
    n = n / n.norm(dim=1, keepdim=True)
    r = torch.linspace(0.05, 0.8, b).view(b, 1, 1, 1).expand(b, 1, size, size).clone()
    return ms.SVBRDF(normal=n, diffuse=torch.rand(b, 3, 1, 1, generator=g).expand(b, 3, size, size).clone(),
                     roughness=r, specular=torch.full((b, 3, size, size), 0.04)).to(device)


def timed(fn, repeats: int) -> float:
    out = []
    for _ in range(repeats):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        out.append(time.perf_counter() - t0)
    return min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 4, 16, 64])
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 8])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--estimators", default=f"plain,plain-frozen,stratified,{DEFAULT}", help="comma-separated names")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--no-reference", action="store_true", help="skip the error column")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    load = OtherLoad()
    if args.quick:
        args.size, args.spp, args.batches, args.repeats = 64, [1, 16], [1], 1
    device = torch.device(args.device)
    rigs = estimator_rigs(Path(tempfile.mkdtemp(prefix="mitsuba_speed-")), args.estimators.split(","))
    rig = rigs[next(iter(rigs))]
    pats = monograd().to(device)
    ref = None
    if not args.no_reference:
        with torch.no_grad():
            ref = ms.render(materials(1, args.size, "cpu"), monograd(), rig).to(device)
    rows = []
    for (est, rig), b in ((e, b) for e in rigs.items() for b in args.batches):
        m = materials(b, args.size, device)
        for spp in args.spp:
            with torch.no_grad():
                ms.render(m, pats, rig, method="mitsuba", spp=spp)  # compile

                def fresh():
                    LAST_MATERIALS.clear()
                    ms.render(m, pats, rig, method="mitsuba", spp=spp, seed=1)

                fwd = timed(fresh, args.repeats)
                ms.render(m, pats, rig, method="mitsuba", spp=spp, seed=1)
                again = timed(lambda: ms.render(m, pats, rig, method="mitsuba", spp=spp, seed=1), args.repeats)
                err = None
                if ref is not None and b == 1:
                    img = ms.render(m, pats, rig, method="mitsuba", spp=spp, seed=2)
                    err = ((img - ref).square().mean().sqrt() / ref.square().mean().sqrt()).item()

            def fwd_bwd():
                p = pats.clone().requires_grad_(True)
                mm = m.detach().requires_grad_(True)
                ms.render(mm, p, rig, method="mitsuba", spp=spp, seed=3).sum().backward()

            fwd_bwd()
            both = timed(fwd_bwd, args.repeats)
            rows.append({"device": device.type, "estimator": est, "B": b, "P": 5, "size": args.size, "spp": spp,
                         "forward_ms": round(fwd * 1e3, 1),
                         "forward_same_maps_ms": round(again * 1e3, 1), "forward_backward_ms": round(both * 1e3, 1),
                         "rel_rmse_vs_reference": None if err is None else round(err, 4)})
            print(rows[-1], flush=True)
    name = torch.cuda.get_device_name(0) if device.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    lines = [f"Mitsuba renderer (`method=\"mitsuba\"`) on {name}, {args.size}x{args.size}, P = 5 patterns. "
             f"{load.sentence()}", "",
             "| estimator | B | spp | forward (ms) | forward, same maps again (ms) | forward+backward (ms) | "
             "rel. RMSE vs reference (B=1) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['estimator']} | {r['B']} | {r['spp']} | {r['forward_ms']} | {r['forward_same_maps_ms']} | "
              f"{r['forward_backward_ms']} | "
              f"{'' if r['rel_rmse_vs_reference'] is None else r['rel_rmse_vs_reference']} |" for r in rows]
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.quick:
        write_report(args.out, f"mitsuba_speed_{device.type}", "Mitsuba renderer speed", "mitsuba_speed.py",
                     text, rows)


if __name__ == "__main__":
    main()
