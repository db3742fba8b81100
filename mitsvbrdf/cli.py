"""Command line interface: ``python -m mitsvbrdf <command> ...`` (or the ``mitsvbrdf`` script).

Commands:
    demo [--out DIR]
        The whole method on the bundled material with the shipped networks (the main job).
    evaluate --model NETWORKS --data DIR|procedural --out DIR [--baseline NAME=NETWORKS ...]
             [--adaptive NAME=NETWORKS ...] [--uniform-lpdf NAME=NETWORKS ...]
        Map and re-rendering metrics of the adaptive method, its variants and the baselines;
        tables, figures, HTML.
    train CONFIG [--resume | --overwrite] [--set key=value ...] [--out DIR] [--time-budget 2h]
        Train one stage of the method (init, stage1, stage2, finetune, fixed) from a TOML config.
    train-chain CHAIN [--time-budget 2h] [--overwrite] [--set key=value ...] [--out DIR]
        The whole chain init -> stage1 -> stage2 -> finetune in one time budget; resumable.
    capture --out SESSION_DIR [--scene S] [--resume] (--simulate MATERIAL | --camera-folder DIR ...)
        The adaptive acquisition at the bench, every frame on disk as it arrives (docs/capture.md).
    calibrate {response,display,color,geometry,intrinsics} --scene S --out S2 ...
        Calibrate the bench; each result is written into a copy of the scene file.
    scene --out FILE
        Copy the default rig's scene file (shipped in the package) out, to edit or calibrate.
    simulate SCENE --material PATH --patterns NAME_OR_FILE --out DIR
        Render the capture of a material under patterns through the scene's rig and display
        model; writes one EXR (linear radiance) and one tone-mapped PNG per pattern, the patterns
        as a PNG strip, the L_pdf of the material and a JSON record of the run.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from . import imageio
from .acquisition import SIMULATE_SEED_MAX, check_resolution, load_adaptive, load_baseline, size_multiple
from .capture.cli import add_parsers as add_capture_parsers
from .checks import check_float, check_int, check_out_dir, check_out_file, check_seed
from .data import preview, procedural
from .demo import DEFAULT_MATERIAL, DEFAULT_NETWORKS, run_demo
from .errors import MitsvbrdfError
from .evaluation import evaluate, load_materials, simulated
from .importance import importance
from .patterns import load_patterns, pca_patterns
from .render import QuadratureSettings, render
from .resolution import DEFAULT_TRANSFER, TRANSFER_HELP, TRANSFER_MODES
from .rig import DEFAULT_SCENE, Rig
from .svbrdf import SVBRDF
from .training import TrainingInterrupted, load_config, train
from .training.chain import load_chain, run_chain
from .training.config import parse_duration
from .training.trainer import RUN_FILES
from .viewing import auto_exposure, pattern_strip, to_uint8, tonemap


def cmd_simulate(args: argparse.Namespace) -> int:
    # Every value is checked, and every input read, before rendering; the folder is made last.
    if args.resolution is not None:
        check_int("--resolution", args.resolution, 1)
    check_int("--spp", args.spp, 1)
    check_seed("--seed", args.seed)
    check_int("--cell-order", args.cell_order, 1)
    check_int("--lobe-grid", args.lobe_grid, 0)
    out = check_out_dir("--out", args.out)
    rig = Rig.from_scene(args.scene)
    svbrdf = SVBRDF.load(args.material)
    if args.resolution is not None:
        svbrdf = svbrdf.resized(args.resolution)
    h, w = rig.lcd_cells
    patterns = load_patterns(args.patterns, h, w)
    rig.check_patterns(patterns)
    settings = QuadratureSettings(cell_order=args.cell_order, lobe_grid=args.lobe_grid)
    H, W = svbrdf.resolution
    started = time.time()
    if args.method == "mitsuba":
        # One pass renders every pattern; the bar marks the pass (the first also compiles kernels).
        with torch.no_grad(), tqdm(total=1, unit="pass", desc=f"render {patterns.shape[0]} patterns "
                                   f"(Mitsuba, {args.spp} spp)", disable=args.quiet) as bar:
            images = render(svbrdf, patterns, rig, method="mitsuba", spp=args.spp, seed=args.seed)[0]
            bar.update(1)
    else:
        with torch.no_grad(), tqdm(total=H * W, unit="px", desc=f"render {patterns.shape[0]} patterns",
                                   disable=args.quiet) as bar:
            images = render(svbrdf, patterns, rig, method=args.method, settings=settings, progress=bar.update)[0]
    render_s = time.time() - started
    peak = float(np.percentile(images.numpy(), 99.5))  # recorded as measured: 0 for a black capture
    exposure = auto_exposure(images)  # one for the set: the PNGs compare the patterns
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for k, img in enumerate(images):
        arr = img.permute(1, 2, 0).numpy()
        imageio.write_exr(out / f"image_{k:02d}.exr", arr)
        imageio.write_png(out / f"image_{k:02d}.png", to_uint8(tonemap(arr, exposure)))
        written += [f"image_{k:02d}.exr", f"image_{k:02d}.png"]
    imageio.write_png(out / "patterns.png", pattern_strip(patterns))
    with torch.no_grad():
        lpdf = importance(svbrdf.normal, svbrdf.roughness, rig, texel_stride=max(1, H // 64))[0, 0]
    imageio.write_png(out / "lpdf.png", lpdf.numpy()[..., None].repeat(3, -1))
    svbrdf.save(out / "material.png")
    written += ["patterns.png", "lpdf.png", "material.png"]
    record = {
        "scene": str(args.scene), "material": str(args.material), "patterns": str(args.patterns),
        "method": args.method, "resolution": [H, W], "lcd_cells": [h, w],
        "settings": ({"spp": args.spp, "seed": args.seed} if args.method == "mitsuba" else
                     {"cell_order": settings.cell_order, "lobe_grid": settings.lobe_grid,
                      "window": settings.window}),
        "render_seconds": round(render_s, 3), "radiance_p99_5": peak, "files": written,
    }
    (out / "simulation.json").write_text(json.dumps(record, indent=2))
    print(f"wrote {len(written) + 1} files to {out} (render {render_s:.1f} s for "
          f"{patterns.shape[0]} patterns at {H}x{W})")
    return 0


def cmd_materials_preview(args: argparse.Namespace) -> int:
    """``materials preview``: a contact sheet of generated materials (maps + a reference render)."""
    for name, value, low in (("--n", args.n, 1), ("--size", args.size, 1), ("--tile", args.tile, 1),
                             ("--columns", args.columns, 1), ("--render-size", args.render_size, 0),
                             ("--start", args.start, 0)):
        check_int(name, value, low)
    check_float("--bump", args.bump, 0.0)
    check_float("--dark-metals", args.dark_metals, 0.0, 1.0)
    check_out_file("--out", args.out)
    families = [f.strip() for f in args.families.split(",") if f.strip()] if args.families else None
    started = time.time()
    svbrdf = procedural.generate(args.n, size=args.size, seed=args.seed, families=families, start=args.start,
                                 bump=args.bump, dark_metals=args.dark_metals)
    gen_s = time.time() - started
    labels = [f"{args.start + i}: {procedural.family_of(args.start + i, args.seed, families)}" for i in range(args.n)]
    renders = None
    if args.render_size > 0:
        rig = Rig.from_scene(args.scene)
        h, w = rig.lcd_cells
        patterns = load_patterns(args.pattern, h, w)
        rig.check_patterns(patterns)
        with tqdm(total=args.n, unit="material", desc="render", disable=args.quiet) as bar:
            renders = preview.render_previews(svbrdf, rig, patterns, size=args.render_size, progress=bar.update)
    sheet = preview.contact_sheet(svbrdf, renders, tile=args.tile, columns=args.columns, labels=labels)
    imageio.write_png(args.out, sheet)
    print(f"wrote {args.out}: {args.n} materials (generated in {gen_s:.2f} s; tiles normal | diffuse | "
          f"roughness | specular{' | render' if renders is not None else ''})")
    return 0


def cmd_scene(args: argparse.Namespace) -> int:
    out = check_out_file("--out", args.out)
    if out.exists():
        raise MitsvbrdfError(f"--out {str(out)!r} exists (perhaps a calibrated rig): remove it or choose "
                             "another name")
    out.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(DEFAULT_SCENE, out)
    print(f"wrote {out}: the default rig ({DEFAULT_SCENE.name}); pass it to --scene, e.g. of calibrate")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    check_int("--resolution", args.resolution, 1)
    check_int("--spp", args.spp, 1)
    check_int("--seed", args.seed, 0, SIMULATE_SEED_MAX)
    check_out_dir("--out", args.out)
    rec = run_demo(args.out, material=args.material or DEFAULT_MATERIAL, networks=args.networks or DEFAULT_NETWORKS,
                   scene=args.scene, resolution=args.resolution, spp=args.spp, seed=args.seed,
                   transfer=args.transfer, progress=not args.quiet)
    m = rec["metrics"]
    print(f"wrote {args.out}/report.html: map RMSE {m['rmse_average']:.4f} (normal {m['rmse_normal']:.4f}, diffuse "
          f"{m['rmse_diffuse']:.4f}, roughness {m['rmse_roughness']:.4f}, specular {m['rmse_specular']:.4f}), "
          f"re-render RMSE {m['rerender_rmse']:.4f}, SSIM {m['ssim']:.3f}; {rec['seconds']['total']} s")
    return 0


def _named(spec: str, option: str) -> tuple[str, str]:
    name, sep, path = spec.partition("=")
    if not sep or not name or not path:
        raise MitsvbrdfError(f"{option} expects NAME=NETWORKS.pt, got {spec!r}")
    return name, path


def cmd_evaluate(args: argparse.Namespace) -> int:
    if args.figures is not None and args.figures < 0:  # before the networks and materials load
        raise MitsvbrdfError(f"--figures must be >= 0, got {args.figures}")
    check_int("--size", args.size, 1)
    check_int("--n", args.n, 1 if args.data == "procedural" else 0)  # 0: every material of a folder
    check_int("--spp", args.spp, 1)
    check_int("--seed", args.seed, 0, SIMULATE_SEED_MAX)
    check_out_dir("--out", args.out)
    rig = Rig.from_scene(args.scene)
    # each export says how it was trained (L_pdf source and stride, I^spec); --uniform-lpdf
    # forces the uniform L_pdf on exports written before they said so
    runs = [("adaptive", args.model, None)]
    runs += [(*_named(s, "--adaptive"), None) for s in args.adaptive or []]
    runs += [(*_named(s, "--uniform-lpdf"), "uniform") for s in args.uniform_lpdf or []]
    acquisitions = {}
    for name, path, lpdf_from in runs:
        acquisitions[name] = load_adaptive(path, rig, lpdf_from=lpdf_from, transfer=args.transfer)
    for spec in args.baseline or []:
        name, path = _named(spec, "--baseline")
        if name in acquisitions:
            raise MitsvbrdfError(f"two methods are named {name!r}")
        acquisitions[name] = load_baseline(path, rig, transfer=args.transfer)
    methods = {name: simulated(a, spp=args.spp, seed=args.seed) for name, a in acquisitions.items()}
    # The networks decide which sizes they take: check before any material is loaded or rendered.
    check_resolution(args.size, size_multiple(*acquisitions.values()), "--size")
    materials = load_materials(args.data, args.size, args.n)
    evaluate(methods, materials, rig, args.out, max_figures=args.figures, progress=not args.quiet)
    print((Path(args.out) / "summary.md").read_text())
    return 0


def cmd_patterns_pca(args: argparse.Namespace) -> int:
    check_int("--count", args.count, 1)
    check_int("--n", args.n, args.count)  # the PCA of `count` patterns needs that many L_pdf maps
    check_int("--size", args.size, 1)
    check_int("--stride", args.stride, 1, args.size)
    out = check_out_file("--out", args.out)
    rig = Rig.from_scene(args.scene)
    lp = []
    for start in range(0, args.n, 16):
        mats = procedural.generate(min(16, args.n - start), size=args.size, seed=args.seed, start=start)
        with torch.no_grad():
            lp.append(importance(mats.normal, mats.roughness, rig, texel_stride=args.stride))
    pats = pca_patterns(torch.cat(lp), n=args.count)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.save(out, pats.numpy())
    print(f"wrote {out}: {args.count} PCA patterns from the L_pdf of {args.n} training materials (seed {args.seed})")
    return 0


def cmd_average_networks(args: argparse.Namespace) -> int:
    from .nets.io import average_exports, write_network_file

    if len(args.exports) < 2:
        raise MitsvbrdfError(f"average-networks needs at least two exports, got {len(args.exports)}")
    out = check_out_file("--out", args.out)
    write_network_file(out, average_exports(args.exports))
    print(f"wrote {out}: the weight average of {len(args.exports)} exports ({', '.join(args.exports)})")
    return 0


def cmd_replace_networks(args: argparse.Namespace) -> int:
    from .nets.io import replace_networks, write_network_file

    out = check_out_file("--out", args.out)
    write_network_file(out, replace_networks(args.base, args.donor, args.networks))
    print(f"wrote {out}: {args.base} with {', '.join(args.networks)} from {args.donor}")
    return 0


def cmd_train_chain(args: argparse.Namespace) -> int:
    chain = load_chain(args.chain, time_budget=args.time_budget, out=args.out)
    check_out_dir("--out" if args.out else f"{args.chain}: out", chain.out)
    try:
        record = run_chain(chain, progress=not args.quiet, overwrite=args.overwrite, extra=list(args.set or []))
    except TrainingInterrupted as e:
        print(f"\nmitsvbrdf: {e}; run the same command again to continue the chain", file=sys.stderr)
        return 128 + e.signal
    for s in record["stages"]:
        print(f"{s['stage']}: {s['steps']} steps in {s['elapsed_s']:.0f} s (budget {s['budget_s']:.0f} s)")
    print(f"networks: {chain.out / 'networks.pt'}; record: {chain.out / 'chain.json'}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    overrides = list(args.set or [])
    if args.out:
        overrides.append(f'out="{args.out}"')
    if args.time_budget:
        overrides.append(f"train.time_budget={parse_duration(args.time_budget)}")
    cfg = load_config(args.config, overrides)
    check_out_dir("--out" if args.out else f"{args.config}: out", cfg.out)

    def written() -> str:  # only what is on disk now
        return ", ".join(f for f in ("config.json", *RUN_FILES) if (Path(cfg.out) / f).is_file()) or "nothing"

    try:
        last = train(cfg, resume=args.resume, overwrite=args.overwrite, progress=not args.quiet)
    except TrainingInterrupted as e:
        print(f"\nmitsvbrdf: {e}; files in {cfg.out}: {written()}", file=sys.stderr)
        return 128 + e.signal
    if last:
        print("last logged: " + ", ".join(f"{k}={v:.4g}" for k, v in last.items() if isinstance(v, float)))
        budget = cfg.train.time_budget
        if budget > 0 and last["step"] >= cfg.train.steps and last["seconds"] < budget:
            # train.steps caps a budgeted run (docs/training.md); say so where a user sees the run end early
            print(f"mitsvbrdf train: stopped at train.steps = {cfg.train.steps} after {last['seconds']:.0f} s of "
                  f"the {budget:.0f} s time budget; raise train.steps (e.g. --set train.steps=1000000) to spend "
                  "the budget", file=sys.stderr)
    print(f"outputs in {cfg.out}: {written()}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mitsvbrdf", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="render a simulated capture through a scene file")
    s.add_argument("scene", help="Mitsuba scene file of the rig, e.g. the default one copied out by "
                   "`mitsvbrdf scene --out rig.xml`")
    s.add_argument("--material", required=True, help="SVBRDF: strip PNG, folder of maps, or EXR")
    s.add_argument("--patterns", default="monograd",
                   help="pattern family (uniform, monograd, colorgrad, step_edges, random) or a "
                        ".npy/.pt/PNG file")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--resolution", type=int, default=None, help="resample the maps to N x N first (N >= 1)")
    s.add_argument("--method", default="mitsuba", choices=["mitsuba", "reference"],
                   help="mitsuba: path-traced through the scene's own plugins (default); reference: "
                        "the deterministic torch quadrature")
    s.add_argument("--spp", type=int, default=64, help="mitsuba: samples per texel")
    s.add_argument("--seed", type=int, default=0, help="mitsuba: sampler seed")
    s.add_argument("--cell-order", type=int, default=2, help="reference: Gauss points per cell axis")
    s.add_argument("--lobe-grid", type=int, default=32, help="reference: sqrt of lobe points per pixel")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_simulate)
    mat = sub.add_parser("materials", help="procedural materials")
    msub = mat.add_subparsers(dest="materials_command", required=True)
    m = msub.add_parser("preview", help="contact sheet of generated materials: 4 maps + a reference render each")
    m.add_argument("--n", type=int, default=16, help="number of materials (default 16)")
    m.add_argument("--out", required=True, help="output PNG")
    m.add_argument("--seed", type=int, default=0, help="stream seed")
    m.add_argument("--start", type=int, default=0, help="index of the first material in the stream")
    m.add_argument("--families", default="", help="comma-separated families (default: all)")
    m.add_argument("--size", type=int, default=256, help="generated resolution (default 256)")
    m.add_argument("--bump", type=float, default=1.0, help="relief multiplier (default 1)")
    m.add_argument("--dark-metals", type=float, default=0.0,
                   help="fraction of materials with dark pure metals, F0 0.03-0.3 (default 0)")
    m.add_argument("--tile", type=int, default=128, help="displayed tile size in px (default 128)")
    m.add_argument("--columns", type=int, default=2, help="materials side by side (default 2)")
    m.add_argument("--render-size", type=int, default=64,
                   help="resolution of the reference render (default 64; 0 = no render)")
    m.add_argument("--scene", default=None, help="rig scene file (default: the package's default rig)")
    m.add_argument("--pattern", default="uniform", help="pattern family or file; its first pattern is used")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.set_defaults(func=cmd_materials_preview)
    pt = sub.add_parser("patterns", help="pattern groups")
    psub = pt.add_subparsers(dest="patterns_command", required=True)
    pc = psub.add_parser("pca", help="the PCA group: mean + principal components of training materials' L_pdf")
    pc.add_argument("--out", required=True, help="output .npy (P, 3, h, w)")
    pc.add_argument("--n", type=int, default=256, help="training materials (default 256)")
    pc.add_argument("--size", type=int, default=64, help="their resolution (default 64)")
    pc.add_argument("--stride", type=int, default=2, help="L_pdf texel stride (default 2)")
    pc.add_argument("--count", type=int, default=5, help="patterns (default 5)")
    pc.add_argument("--seed", type=int, default=0, help="procedural stream seed (training seeds)")
    pc.add_argument("--scene", default=None)
    pc.set_defaults(func=cmd_patterns_pca)
    t = sub.add_parser("train", help="train a stage from a TOML config (see train/ and docs/training.md)")
    t.add_argument("config", help="config file, e.g. train/stage1-small.toml")
    t.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt (the settings must "
                   "match, except those listed in docs/training.md, e.g. more train.steps)")
    t.add_argument("--overwrite", action="store_true", help="start again in a folder that holds a run (its "
                   "checkpoint, networks, metrics and plot are removed)")
    t.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a config key, e.g. train.steps=10")
    t.add_argument("--out", default="", help="output folder (overrides the config's out)")
    t.add_argument("--time-budget", default="", metavar="DURATION", help="end the run after this much training "
                   "time (e.g. 2h, 90m), the learning-rate schedule fitted to it (train.time_budget)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_train)
    tc = sub.add_parser("train-chain", help="train init -> stage1 -> stage2 -> finetune in one time budget "
                        "(a chain file, e.g. train/chains/small.toml; resumable)")
    tc.add_argument("chain", help="chain file listing the stage configs and their shares of the budget")
    tc.add_argument("--time-budget", default=None, metavar="DURATION", help="total training time (e.g. 2h), "
                    "instead of the file's time_budget")
    tc.add_argument("--out", default=None, help="output folder (instead of the file's out)")
    tc.add_argument("--overwrite", action="store_true", help="start again (removes OUT); without it a chain "
                    "continues where it stopped")
    tc.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key in every stage")
    tc.add_argument("--quiet", action="store_true", help="no progress bars")
    tc.set_defaults(func=cmd_train_chain)
    av = sub.add_parser("average-networks", help="the weight average of exports of one chain's runs (e.g. "
                        "continuations of one export under other seeds or losses)")
    av.add_argument("exports", nargs="+", help="networks.pt files: the same networks and acquisition settings")
    av.add_argument("--out", required=True, help="output networks.pt")
    av.set_defaults(func=cmd_average_networks)
    rp = sub.add_parser("replace-networks", help="an export with some of its networks taken from another "
                        "(e.g. an initializer trained further, put back in front of its G_l and G_sc)")
    rp.add_argument("base", help="networks.pt whose other networks and acquisition settings stay")
    rp.add_argument("--from", dest="donor", required=True, help="networks.pt to take the networks from")
    rp.add_argument("--networks", nargs="+", required=True, metavar="NAME",
                    help="names of the networks to take (e.g. l0 initializer)")
    rp.add_argument("--out", required=True, help="output networks.pt")
    rp.set_defaults(func=cmd_replace_networks)
    sc = sub.add_parser("scene", help="copy the default rig's scene file out (to edit it or calibrate into it)")
    sc.add_argument("--out", required=True, help="scene file to write (refused when it exists)")
    sc.set_defaults(func=cmd_scene)
    d = sub.add_parser("demo", help="the whole method on the bundled material with the shipped networks")
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.add_argument("--material", default="", help="material to acquire (default: the bundled example)")
    d.add_argument("--networks", default="", help="networks.pt of stage2/finetune (default: the shipped weights)")
    d.add_argument("--scene", default=None, help="rig scene file (default: the package's default rig)")
    d.add_argument("--resolution", type=int, default=256, help="material resolution (default 256)")
    d.add_argument("--spp", type=int, default=64, help="Mitsuba samples per texel (default 64)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--transfer", default=DEFAULT_TRANSFER, choices=TRANSFER_MODES, help=TRANSFER_HELP)
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_demo)
    e = sub.add_parser("evaluate", help="score the adaptive method (and baselines) on a set of materials")
    e.add_argument("--model", required=True, help="networks.pt of stage2/finetune")
    e.add_argument("--adaptive", action="append", metavar="NAME=NETWORKS.pt",
                   help="another adaptive run (stage2/finetune export), e.g. a variant without I^spec")
    e.add_argument("--uniform-lpdf", action="append", metavar="NAME=NETWORKS.pt",
                   help="an adaptive run forced to predict its patterns from a uniform L_pdf (the Diff. Init. "
                        "ablation). Exports say how they were trained, so --adaptive is enough for them; "
                        "this is for exports written before they did")
    e.add_argument("--baseline", action="append", metavar="NAME=NETWORKS.pt",
                   help="a baseline run (export of a 'fixed' stage: fixed or learned patterns, or flash)")
    e.add_argument("--data", default="procedural", help="'procedural' (held-out seeds) or a folder of materials")
    e.add_argument("--n", type=int, default=16, help="number of materials (0: all in the folder)")
    e.add_argument("--size", type=int, default=256, help="materials are resampled to size x size")
    e.add_argument("--spp", type=int, default=64)
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--scene", default=None)
    e.add_argument("--transfer", default=DEFAULT_TRANSFER, choices=TRANSFER_MODES, help=TRANSFER_HELP)
    e.add_argument("--figures", type=int, default=None, metavar="N",
                   help="figures for the first N materials only (default: every material)")
    e.add_argument("--out", required=True, help="output folder")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(func=cmd_evaluate)
    add_capture_parsers(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except MitsvbrdfError as e:
        print(f"mitsvbrdf: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C outside train's own handling (which checkpoints first)
        print("\nmitsvbrdf: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
