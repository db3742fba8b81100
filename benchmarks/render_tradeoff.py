"""Speed/accuracy trade of the renderers against the reference: LTC (exact, prefiltered), and the
Mitsuba path with each estimator of the ``importance`` integrator.

    .venv/bin/python benchmarks/render_tradeoff.py            # writes docs/benchmarks/render_tradeoff*.{md,csv,png}
    .venv/bin/python benchmarks/render_tradeoff.py --quick    # smoke run, nothing written
    .venv/bin/python benchmarks/render_tradeoff.py --procedural-only --estimators plain,ltc-cells,... --name NAME
        # study 2 alone for some estimators: docs/benchmarks/render_tradeoff_procedural_NAME.{md,csv,png}
    .venv/bin/python benchmarks/render_tradeoff.py --roughness-only --estimators plain,ltc-cells,... --name NAME
        # study 1 alone, each estimator judged: docs/benchmarks/render_tradeoff_roughness_NAME.{md,csv}

Study 1 (roughness): the bundled example's normal and diffuse maps with constant roughness r and
ks = 0.3, for r in {0.01, 0.05, 0.1, 0.3, 0.6, 1.0}, plus a near-grazing case (r = 0.3 with every
normal tilted 70 degrees away from the camera's azimuth). Patterns: MonoGrad, 5 random, 4 step
edges. Error: relative RMSE of each method's images against the reference renderer (default
settings) at ``--error-size``; time: one material under 5 patterns at ``--time-size`` on this
machine's CPU, the median of ``--time-rounds`` renders taken in interleaved rounds of every method,
each right after an untimed one of the same (Mitsuba estimators with the other scenes released;
LTC-exact, which takes seconds, one render). For every roughness it also states whether the default estimator, at the CPU time
of LTC-prefiltered (interpolated on its error-vs-time curve), has at most half LTC-prefiltered's
error.

Study 2 (procedural): ``generate(4, size=64, seed=123)`` under MonoGrad, ColorGrad and the shipped
networks' adaptive patterns (L_0 + the 4 predicted for each material); relative RMSE per material
and pattern group for every estimator and spp, and time per batch under MonoGrad: the median of
``--time-rounds`` renders taken in interleaved rounds, one of every estimator and spp per round, each
right after an untimed one of the same with the other scenes released (as benchmarks/cv_cost.py
times them: taken one estimator after another, the later ones ran slower; ``render_alone`` in
estimators.py says why the others' scenes go).
It prints the default estimator's worst 4-spp error (the goal: <= 0.05) and its time against
plain's at 4 spp (the goal: <= 1.5x).

Estimators (:data:`ESTIMATORS`, integrator options in a copy of the scene file): "plain" (the
integrator before control variates: independent samples, no control variate, its kernels traced at
every render), "plain-frozen" (the same, replaying its recorded kernels as all the others do),
"stratified",
"diffuse-cv", "ltc-cv" (one radiance per texel for the specular lobe), "ltc-cv" with 4 and 16
blocks and with the LCD sampled by the patterns' brightness, "ltc-cells" (both lobes under every
cell's radiance, lobe grid 16, narrow lobes under an 8 x 8 window of cells) without the window,
with a 4 x 4 one, with grids 8 (with and without the window) and 32, and "ltc-grid" (the per-cell
terms in the integrator's kernels) on grids 4 and 8 without a window, and with 4 x 4 and 8 x 8
windows ("ltc-grid-window-8", grid 4: the default; "ltc-grid-window-8-traced" the same tracing its
kernels at every render).
Prints tables, writes CSV + markdown, and plots of error vs. time and vs. spp.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import torch

import mitsvbrdf as ms
from mitsvbrdf.demo import DEFAULT_MATERIAL
from mitsvbrdf.patterns import colorgrad, monograd, random, step_edges
from mitsvbrdf.render.control_variate import LAST_MATERIALS
from estimators import DEFAULT, ESTIMATORS, estimator_names, estimator_rigs, render_alone
from report import OtherLoad, interleaved_seconds, write_report

ROOT = Path(__file__).resolve().parent.parent
SPPS = (1, 4, 16, 64, 256)


def material(size: int, roughness: float, tilt_deg: float | None = None) -> ms.SVBRDF:
    base = ms.SVBRDF.load(DEFAULT_MATERIAL).resized(size)
    normal = base.normal
    if tilt_deg is not None:
        t = math.radians(tilt_deg)
        normal = torch.tensor([-math.sin(t), 0.0, math.cos(t)]).view(1, 3, 1, 1).expand_as(normal).contiguous()
    return ms.SVBRDF(normal=normal, diffuse=base.diffuse, roughness=torch.full_like(base.roughness, roughness),
                     specular=torch.full_like(base.specular, 0.3))


TILTS = (0.0, 10.0, 30.0, 60.0, 75.0)
BIAS_ROUGHNESS = (0.01, 0.03, 0.1, 0.3, 0.6, 1.0)


def tilted_normal(rig: ms.Rig, tilt_deg: float) -> tuple[float, float, float]:
    """Unit normal tilted ``tilt_deg`` away from the LCD's azimuth (75 degrees: the LCD crosses the
    horizon of the normal)."""
    lcd = rig.lcd_corners.mean(0)
    az = math.atan2(float(lcd[1]), float(lcd[0])) + math.pi
    t = math.radians(tilt_deg)
    return (math.sin(t) * math.cos(az), math.sin(t) * math.sin(az), math.cos(t))


def uniform_lcd_bias(rig: ms.Rig, size: int = 8) -> list[dict]:
    """LTC-exact specular lobe under one uniformly lit LCD vs the reference: relative RMSE per
    (tilt, roughness), and the reference's mean radiance (to tell large errors of tiny signals)."""
    rows = []
    p = torch.ones(1, 3, *rig.lcd_cells)
    for tilt in TILTS:
        row = {"tilt_deg": tilt}
        for r in BIAS_ROUGHNESS:
            m = ms.SVBRDF.constant(normal=tilted_normal(rig, tilt), diffuse=0.5, roughness=r, specular=0.5, size=size)
            ref = ms.render(m, p, rig, lobes="specular")
            ltc = ms.render(m, p, rig, method="ltc", lobes="specular")
            row[f"r={r}"] = round(((ltc - ref).square().mean().sqrt() / ref.square().mean().sqrt()).item(), 5)
            row[f"ref_mean r={r}"] = float(f"{ref.mean().item():.3g}")
        rows.append(row)
    return rows


def methods(rigs: dict[str, ms.Rig], spps=SPPS):
    """(name, render function(svbrdf, patterns, seed)) for every method of the study."""
    base = rigs[DEFAULT]
    out = [("ltc-exact", lambda m, p, s: ms.render(m, p, base, method="ltc", mode="exact")),
           ("ltc-prefiltered", lambda m, p, s: ms.render(m, p, base, method="ltc", mode="prefiltered"))]
    for est, rig in rigs.items():
        for spp in spps:
            out.append((f"{est}-{spp}spp",
                        lambda m, p, s, spp=spp, rig=rig: render_alone(m, p, rig, spp, seed=s)))
    return out


def rel_rmse(img: torch.Tensor, ref: torch.Tensor) -> float:
    return ((img - ref).square().mean().sqrt() / ref.square().mean().sqrt()).item()


def timed(fn, *args, repeats: int = 3) -> float:
    """Seconds of one call after a warm-up call (kernels compiled, geometry caches filled): the
    fastest of ``repeats``, since other work on a shared machine only ever adds time. Each call
    starts without the last materials' control-variate terms, as a first capture of new
    materials does (a second capture of the same materials reuses them; mitsuba_speed.py times
    that too)."""
    fn(*args[:-1], 0)
    best = math.inf
    for _ in range(repeats):
        LAST_MATERIALS.clear()
        t0 = time.perf_counter()
        fn(*args)
        best = min(best, time.perf_counter() - t0)
    return best


#: the time columns of the roughness study: a wide-lobe material (roughness 0.3) and a narrow-lobe
#: one (0.1: the window term's range, whose cost the wide one does not see)
TIME_ROUGHNESS = {"seconds_per_material_5_patterns": 0.3, "seconds_narrow": 0.1}
#: roughness columns below this are judged at the narrow material's times
NARROW_BELOW = 0.2


def time_key(key: str) -> str:
    """The time column that prices the roughness-study column ``key`` ("r=0.05", "r=0.3,tilt=70")."""
    r = float(key.split(",")[0][2:])
    return "seconds_narrow" if r < NARROW_BELOW else "seconds_per_material_5_patterns"


def spp_rows(rows: list[dict], est: str) -> list[dict]:
    """The rows of estimator ``est``'s spp curve (methods "<est>-<n>spp")."""
    return [r for r in rows if r["method"].startswith(est + "-") and r["method"][len(est) + 1:].rstrip("spp").isdigit()]


def at_time(rows: list[dict], est: str, key: str, seconds: float, time_column: str) -> float | None:
    """Error of estimator ``est`` at ``seconds`` of ``time_column``, interpolated log-log along its
    spp curve (its last point beyond the measured range; None when even its fastest point takes
    longer: it has no estimate in that time)."""
    pts = sorted((r[time_column], r[key]) for r in spp_rows(rows, est))
    if seconds < pts[0][0]:
        return None
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if t0 <= seconds <= t1:
            f = (math.log(seconds) - math.log(t0)) / max(math.log(t1) - math.log(t0), 1e-12)
            return math.exp(math.log(e0) + f * (math.log(e1) - math.log(e0)))
    return pts[-1][1]


def procedural_study(rigs: dict[str, ms.Rig], n: int, size: int, spps, rounds: int = 7) -> tuple[list[dict], list[str]]:
    """Study 2: per estimator and spp, relative RMSE per (pattern group, material) and time (the
    median of ``rounds`` interleaved rounds)."""
    load = OtherLoad()
    from mitsvbrdf.data.procedural import generate
    from mitsvbrdf.acquisition import DEFAULT_NETWORKS, load_adaptive

    mats = generate(n, size=size, seed=123)
    base = rigs[DEFAULT]
    with torch.no_grad():
        acq = load_adaptive(DEFAULT_NETWORKS, base).simulate(mats, method="reference")
    acq = acq if isinstance(acq, list) else [acq]
    groups = {"monograd": monograd(), "colorgrad": colorgrad(), "adaptive": torch.stack([a.patterns for a in acq])}
    refs = {g: ms.render(mats, p, base) for g, p in groups.items()}

    seconds = interleaved_seconds({(est, spp): (lambda rig=rig, spp=spp: render_alone(mats, groups["monograd"], rig, spp))
                                   for est, rig in rigs.items() for spp in spps}, rounds, before=LAST_MATERIALS.clear,
                                  settle=True)
    rows = []
    for est, rig in rigs.items():
        for spp in spps:
            row = {"estimator": est, "spp": spp, "seconds_batch": round(seconds[(est, spp)], 4)}
            for g, p in groups.items():
                img = ms.render(mats, p, rig, method="mitsuba", spp=spp, seed=7)
                for b in range(n):
                    row[f"{g}/{b}"] = round(rel_rmse(img[b], refs[g][b]), 5)
            row["worst"] = max(v for k, v in row.items() if "/" in k)
            row["median"] = float(torch.tensor([v for k, v in row.items() if "/" in k]).median())
            rows.append(row)
            print(row, flush=True)
    keys = [k for k in rows[0] if "/" in k]
    lines = [f"## Procedural materials: every estimator", "",
             f"`generate({n}, size={size}, seed=123)` under MonoGrad, ColorGrad and the shipped networks' adaptive "
             f"patterns (L_0 + 4 predicted per material, from a reference-rendered I_0); relative RMSE against the "
             f"reference per pattern group / material; time for the batch of {n} materials under MonoGrad "
             f"({torch.get_num_threads()} threads; median of {rounds} renders in interleaved rounds of every estimator "
             f"and spp, material cache cleared). {load.sentence()}", "",
             "| estimator | spp | time (s) | median | worst | " + " | ".join(keys) + " |",
             "|---|---:|---:|---:|---:|" + "---:|" * len(keys)]
    lines += [f"| {r['estimator']} | {r['spp']} | {r['seconds_batch']} | {r['median']:.4f} | {r['worst']:.4f} | "
              + " | ".join(f"{r[k]:.4f}" for k in keys) + " |" for r in rows]
    by = {(r["estimator"], r["spp"]): r for r in rows}
    if (DEFAULT, 4) in by and ("plain", 4) in by:
        d, p = by[(DEFAULT, 4)], by[("plain", 4)]
        lines += ["", f"At 4 spp the default estimator ({DEFAULT}) has relative RMSE {min(d[k] for k in keys):.4f}-"
                      f"{d['worst']:.4f} (goal <= 0.05: {'met' if d['worst'] <= 0.05 else 'NOT met'}); the plain "
                      f"estimator {min(p[k] for k in keys):.4f}-{p['worst']:.4f}. Time at 4 spp: "
                      f"{d['seconds_batch']:.3f} s against {p['seconds_batch']:.3f} s "
                      f"({d['seconds_batch'] / p['seconds_batch']:.2f}x; goal <= 1.5x: "
                      f"{'met' if d['seconds_batch'] <= 1.5 * p['seconds_batch'] else 'NOT met'})."]
        if ("plain-frozen", 4) in by:  # the variance reduction's own cost: both replay recorded kernels
            f = by[("plain-frozen", 4)]
            lines[-1] += (f" Against plain-frozen ({f['seconds_batch']:.3f} s, the same kernels as plain, replayed as "
                          f"the default's are): {d['seconds_batch'] / f['seconds_batch']:.2f}x.")
    return rows, lines


def roughness_study(rigs: dict[str, ms.Rig], args, cases, spps, judged: list[str],
                    load: OtherLoad) -> tuple[list, list, list]:
    """Study 1: per method, CPU time and relative RMSE per roughness case; for each estimator of
    ``judged``, whether at LTC-prefiltered's CPU time it has at most half LTC-prefiltered's error.
    Returns the rows, the error columns and the report's lines."""
    rig = rigs[DEFAULT]
    pats = torch.cat([monograd(), random(n=5, seed=0), step_edges(n=4)])
    rows = []
    with torch.no_grad():
        refs = {}
        for r, tilt in cases:
            m = material(args.error_size, r, tilt)
            refs[(r, tilt)] = (m, ms.render(m, pats, rig))
        timed_methods = [(name, fn) for name, fn in methods(rigs, spps)
                         if not (name == "ltc-exact" and (args.skip_ltc_exact or args.quick))]
        on = {column: material(args.time_size, r_time) for column, r_time in TIME_ROUGHNESS.items()}
        # time: one material under 5 patterns, in interleaved rounds (LTC-exact, 10^2 times slower, once)
        seconds = interleaved_seconds({(name, column): (lambda fn=fn, m=m: fn(m, pats[:5], 1))
                                       for name, fn in timed_methods if name != "ltc-exact"
                                       for column, m in on.items()}, args.time_rounds, before=LAST_MATERIALS.clear,
                                      settle=True)
        for name, fn in timed_methods:
            row = {"method": name}
            for column, m in on.items():
                row[column] = round(seconds[(name, column)] if name != "ltc-exact" else timed(fn, m, pats[:5], 1, repeats=1), 4)
            errs = {key: rel_rmse(fn(m, pats, 2), ref) for key, (m, ref) in refs.items()}
            row.update({f"r={r}" + (f",tilt={tilt:g}" if tilt else ""): round(e, 5) for (r, tilt), e in errs.items()})
            rows.append(row)
            print(row, flush=True)

    keys = [k for k in rows[0] if k.startswith("r=")]
    lines = [f"## Roughness study", "",
             f"Relative RMSE against the reference renderer ({args.error_size}x{args.error_size} px, MonoGrad + "
             f"5 random + 4 step-edge patterns, ks = 0.3, the example's normal map; 'tilt=70' replaces it by normals "
             f"tilted 70 degrees, near-grazing views) and CPU time for one {args.time_size}x{args.time_size} material "
             f"under 5 patterns ({torch.get_num_threads()} threads; median of {args.time_rounds} renders in interleaved "
             f"rounds of every method, LTC-exact one render), at roughness 0.3 and, for the narrow lobes "
             f"(r < {NARROW_BELOW:g}: the window term's range), at 0.1. Mitsuba rows are estimator-spp. "
             f"{load.sentence()}", "",
             "| method | time (s) | time, r=0.1 (s) | " + " | ".join(keys) + " |", "|---|---:|---:|" + "---:|" * len(keys)]
    lines += [f"| {r['method']} | {r['seconds_per_material_5_patterns']} | {r['seconds_narrow']} | " +
              " | ".join(f"{r[k]:.4f}" for k in keys) + " |" for r in rows]
    ltc = {r["method"]: r for r in rows}
    ltc_names = [n for n in ("ltc-exact", "ltc-prefiltered") if n in ltc]
    worst = {k: max(ltc[n][k] for n in ltc_names) for k in keys}
    fails = [f"{k} ({worst[k]:.1%})" for k in keys if worst[k] > 0.05]
    lines += ["", "LTC errors above 5% (worse of its modes): " + (", ".join(fails) if fails else "none") + "."]
    pre = ltc["ltc-prefiltered"]
    for est in judged:
        verdict = []
        for k in keys:
            column = time_key(k)
            e = at_time(rows, est, k, pre[column], column)
            if e is None:
                fastest = min(r[column] for r in spp_rows(rows, est))
                verdict.append(f"{k}: NOT reached, its fastest render takes {fastest:.3f} s against "
                               f"{pre[column]:.3f} s")
            else:
                verdict.append(f"{k}: {e:.4f} vs {pre[k]:.4f} at {pre[column]:.3f} s "
                               f"({'half or less' if e <= 0.5 * pre[k] else 'NOT half'})")
        who = f"the default estimator ({est}, " if est == DEFAULT else f"{est} ("
        lines += ["", f"At LTC-prefiltered's CPU time (on the material of the column's time), {who}interpolated "
                      f"along its spp curve) against LTC-prefiltered: " + "; ".join(verdict) + "."]
    return rows, keys, lines


def roughness_only(rows: list[dict], keys: list[str], lines: list[str], args, names: list[str]) -> None:
    """Study 1 alone for the estimators ``names``, as render_tradeoff_roughness_NAME."""
    command = " ".join(["benchmarks/render_tradeoff.py", "--roughness-only", f"--estimators {','.join(names)}",
                        f"--name {args.name}"] + (["--skip-ltc-exact"] if args.skip_ltc_exact else []))
    text = f"Command: `{command}`\n\n" + "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    write_report(args.out, f"render_tradeoff_roughness_{args.name}", "Estimators on the roughness study",
                 "render_tradeoff.py", text, rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--error-size", type=int, default=32)
    ap.add_argument("--time-size", type=int, default=128)
    ap.add_argument("--procedural-n", type=int, default=4)
    ap.add_argument("--procedural-size", type=int, default=64)
    ap.add_argument("--time-rounds", type=int, default=7, help="interleaved timing rounds of both studies")
    ap.add_argument("--skip-ltc-exact", action="store_true", help="leave out LTC-exact (by far the slowest method at 128 px)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--procedural-only", action="store_true", help="study 2 alone (needs --name)")
    ap.add_argument("--roughness-only", action="store_true",
                    help="study 1 alone, judging every estimator given against LTC-prefiltered (needs --name)")
    ap.add_argument("--estimators", default="", help=f"comma-separated subset of: {', '.join(ESTIMATORS)}")
    ap.add_argument("--name", default="", help="suffix of a --procedural-only or --roughness-only report's files")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    names = estimator_names(args.estimators)
    if args.procedural_only and not args.name:
        ap.error("--procedural-only writes render_tradeoff_procedural_NAME: give --name")
    if args.roughness_only and not args.name:
        ap.error("--roughness-only writes render_tradeoff_roughness_NAME: give --name")
    if args.roughness_only and DEFAULT not in names:
        ap.error(f"--roughness-only renders its references with the default estimator's rig: include {DEFAULT}")
    load = OtherLoad()
    cases = [(r, None) for r in (0.01, 0.05, 0.1, 0.3, 0.6, 1.0)] + [(0.3, 70.0)]
    spps = SPPS
    if args.quick:
        args.error_size, args.time_size, cases, spps = 16, 32, [(0.05, None), (0.6, None)], (1, 4)
        args.procedural_n, args.procedural_size = 2, 16
    work = Path(tempfile.mkdtemp(prefix="render_tradeoff-"))
    rigs = estimator_rigs(work, names)
    if args.procedural_only:
        procedural_only(rigs, args, spps)
        return
    if args.roughness_only:
        rows, keys, lines = roughness_study(rigs, args, cases, spps, [n for n in names if n != "plain"], load)
        roughness_only(rows, keys, lines, args, names)
        return
    rig = rigs[DEFAULT]
    rows, keys, lines = roughness_study(rigs, args, cases, spps, [DEFAULT], load)

    with torch.no_grad():
        proc_rows, proc_lines = procedural_study(rigs, args.procedural_n, args.procedural_size, spps, args.time_rounds)
    lines += [""] + proc_lines

    bias = uniform_lcd_bias(rig, size=8 if not args.quick else 4)
    rkeys = [f"r={r}" for r in BIAS_ROUGHNESS]
    lines += ["", "## One uniformly lit LCD: bias of the LTC specular lobe", "",
              "LTC-exact, specular lobe only, 8x8 px, flat material with every normal tilted away from the LCD's "
              "azimuth (75 degrees: the LCD crosses the normal's horizon). Relative RMSE against the reference; in "
              "brackets the reference's mean radiance (the LCD at drive 1 has radiance 1), so that a large relative "
              "error of a vanishing signal can be told from a real one.", "",
              "| tilt (deg) | " + " | ".join(rkeys) + " |", "|---:|" + "---:|" * len(rkeys)]
    lines += [f"| {b['tilt_deg']:g} | " + " | ".join(f"{b[k]:.4f} ({b['ref_mean ' + k]:.2g})" for k in rkeys) + " |"
              for b in bias]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    write_report(args.out, "render_tradeoff", "Renderer speed/accuracy trade", "render_tradeoff.py", text + "\n"
                 "![error vs time](render_tradeoff.png)\n\n![procedural: error vs spp and time](render_tradeoff_procedural.png)\n",
                 rows)
    write_report(args.out, "render_tradeoff_procedural", "Estimators on procedural materials", "render_tradeoff.py",
                 "See render_tradeoff.md.\n", proc_rows)
    write_report(args.out, "render_tradeoff_uniform_lcd", "LTC bias under one uniform LCD", "render_tradeoff.py",
                 "See render_tradeoff.md.\n", bias)
    plot(rows, keys, proc_rows, args)


def procedural_only(rigs: dict[str, ms.Rig], args, spps) -> None:
    """Study 2 for the estimators of ``rigs`` alone, as render_tradeoff_procedural_NAME."""
    with torch.no_grad():
        rows, lines = procedural_study(rigs, args.procedural_n, args.procedural_size, spps, args.time_rounds)
    command = " ".join(["benchmarks/render_tradeoff.py", "--procedural-only", f"--estimators {','.join(rigs)}",
                        f"--name {args.name}", f"--procedural-n {args.procedural_n}",
                        f"--procedural-size {args.procedural_size}"])
    text = f"Command: `{command}`\n\n" + "\n".join(lines) + "\n"
    print(text)
    if args.quick:
        return
    stem = f"render_tradeoff_procedural_{args.name}"
    write_report(args.out, stem, "Estimators on procedural materials", "render_tradeoff.py",
                 text + f"\n![procedural: error vs spp and time]({stem}.png)\n", rows)
    plot_procedural(rows, args, args.out / f"{stem}.png")


def plot(rows: list[dict], keys: list[str], proc_rows: list[dict], args) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    # median over materials: one grazing outlier would otherwise hide the typical error
    med = {r["method"]: float(torch.tensor([r[k] for k in keys]).median()) for r in rows}
    secs = {r["method"]: r["seconds_per_material_5_patterns"] for r in rows}
    for est in ESTIMATORS:
        names = [r["method"] for r in spp_rows(rows, est)]
        ax.plot([secs[n] for n in names], [med[n] for n in names], "o-", label=f"Mitsuba {est} (1..256 spp)",
                linewidth=2.5 if est == DEFAULT else 1.2)
    for n, marker in (("ltc-exact", "s"), ("ltc-prefiltered", "^")):
        if n in secs:
            ax.plot([secs[n]], [med[n]], marker, markersize=9, label=n)
    ax.set(xscale="log", yscale="log", xlabel=f"CPU seconds per {args.time_size}x{args.time_size} material, 5 patterns",
           ylabel="relative RMSE vs reference (median over materials)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / "render_tradeoff.png", dpi=120)
    plt.close(fig)
    plot_procedural(proc_rows, args, args.out / "render_tradeoff_procedural.png")


def plot_procedural(proc_rows: list[dict], args, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for est in dict.fromkeys(r["estimator"] for r in proc_rows):
        pts = [r for r in proc_rows if r["estimator"] == est]
        for ax, x in zip(axes, ("spp", "seconds_batch")):
            ax.plot([r[x] for r in pts], [r["median"] for r in pts], "o-", label=est,
                    linewidth=2.5 if est == DEFAULT else 1.2)
    for ax, label in zip(axes, ("samples per texel", f"CPU seconds per batch of {args.procedural_n} materials")):
        ax.axhline(0.05, color="grey", linestyle=":", label="5%")
        ax.set(xscale="log", yscale="log", xlabel=label, ylabel="relative RMSE (median over materials and groups)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Procedural {args.procedural_size} px materials: MonoGrad, ColorGrad, adaptive patterns")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
