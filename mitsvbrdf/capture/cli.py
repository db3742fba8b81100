"""``mitsvbrdf capture`` and ``mitsvbrdf calibrate``: the bench commands (see docs/capture.md).

Devices come from the options: ``--simulate MATERIAL`` (the simulated rig, for trying the
commands and for tests) or a real bench (``--camera-folder`` for frames from a tethering tool,
``--display`` for the pattern window or file, ``--controller`` for the serial trigger).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .. import imageio
from ..acquisition import DEFAULT_NETWORKS, load_adaptive
from ..checks import check_float, check_int, check_out_dir, check_out_file, check_seed
from ..errors import MitsvbrdfError
from ..resolution import DEFAULT_TRANSFER, TRANSFER_HELP, TRANSFER_MODES
from ..rig import DEFAULT_SCENE, Rig
from ..svbrdf import SVBRDF
from . import calibrate as cal
from .camera import (CameraModel, calibrate_intrinsics, checkerboard_points, find_checkerboard_corners,
                     write_camera_intrinsics)
from .devices import (DeviceError, FileDropCamera, ImageFileDisplay, SimulatedRig, TriggeredCamera, WindowDisplay,
                      controller_trigger)
from .display import write_display_model
from .geometry import write_lcd_pose
from .scene_file import read_camera_calibration, write_camera_calibration
from .session import BracketCapture, CaptureSession


def exposure_times(text: str, what: str = "--exposures", at_least: int = 1) -> tuple[float, ...]:
    """Comma-separated exposure times in seconds: finite, > 0, and ``at_least`` distinct ones."""
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise MitsvbrdfError(f"{what} must be comma-separated seconds, e.g. 0.01,0.1,1; got {text!r}") from None
    bad = [v for v in vals if not (np.isfinite(v) and v > 0)]
    if bad:
        raise MitsvbrdfError(f"{what} must all be positive, finite seconds; got {text!r}")
    if len(set(vals)) < at_least:
        raise MitsvbrdfError(f"{what} needs at least {at_least} different exposure times here, got {text!r}")
    return vals


def check_device_options(args, exposures_needed: int = 1) -> tuple[float, ...]:
    """Check the numbers of the device options before any device is opened; returns the exposures."""
    check_int("--spp", args.spp, 1)
    check_seed("--seed", args.seed)
    check_float("--gain", args.gain, 0.0, low_open=True)
    check_int("--resolution", args.resolution, 1)
    check_float("--camera-timeout", args.camera_timeout, 0.0, low_open=True)
    return exposure_times(args.exposures, at_least=exposures_needed)


def add_device_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("devices")
    g.add_argument("--simulate", default="", metavar="MATERIAL",
                   help="simulated rig with this material on the sample ('target' for calibration targets)")
    g.add_argument("--truth-scene", default=None, help="simulation: the rig as it really is (default: --scene)")
    g.add_argument("--spp", type=int, default=64, help="simulation: Mitsuba samples per texel")
    g.add_argument("--seed", type=int, default=0, help="simulation: sampler and noise seed")
    g.add_argument("--gain", type=float, default=1.0, help="simulation: relative exposure per radiance and second")
    g.add_argument("--resolution", type=int, default=256, help="texel grid of the sample (default 256)")
    g.add_argument("--camera-folder", default="", help="real camera: folder the tethering tool writes frames into")
    g.add_argument("--camera-linear", action="store_true", help="real camera: frames are linear (RAW/EXR)")
    g.add_argument("--camera-timeout", type=float, default=30.0, help="real camera: seconds to wait per frame")
    g.add_argument("--display", default="window", help="real LCD: 'window' (full screen) or a PNG path to write")
    g.add_argument("--controller", default="", help="serial URL of the trigger controller, e.g. /dev/ttyUSB0, "
                                                    "socket://host:port")
    g.add_argument("--exposures", default="1", help="bracket exposure times in seconds, comma-separated")


def _devices(args, rig, material):
    """(display, camera, response, colour matrix, closers) from the device options."""
    response, matrix = read_camera_calibration(args.scene) if args.scene else (None, None)
    ctl = None
    if args.controller:
        from .controller import ControllerError, SerialController  # pyserial: only for a real controller

        try:
            ctl = SerialController(args.controller)
        except ControllerError as e:
            raise DeviceError(f"--controller {args.controller}: {e}") from e
    if args.simulate:
        truth_scene = args.truth_scene or args.scene
        truth = Rig.from_scene(truth_scene)
        true_response, true_matrix = read_camera_calibration(truth_scene) if truth_scene else (None, None)
        sim = SimulatedRig(material, truth, spp=args.spp, seed=args.seed, gain=args.gain, response=true_response,
                           color_matrix=None if true_matrix is None else np.linalg.inv(true_matrix))
        cam = TriggeredCamera(sim, ctl) if ctl else sim
        return sim, cam, response, matrix, ctl
    if not args.camera_folder:
        raise MitsvbrdfError("give --simulate MATERIAL or a real camera (--camera-folder)")
    cam = FileDropCamera(args.camera_folder, trigger=controller_trigger(ctl) if ctl else None,
                         timeout=args.camera_timeout, linear=args.camera_linear)
    display = WindowDisplay(rig.lcd_cells) if args.display == "window" else ImageFileDisplay(args.display, rig.lcd_cells)
    return display, cam, response, matrix, ctl


def _bracket(args, rig, display, cam, response, matrix, raw_only: bool = False):
    rectify = None
    if not cam.rectified:
        model = CameraModel.from_rig(rig)
        rectify = lambda frame: model.rectify(frame, rig.sample_size, args.resolution)  # noqa: E731
    return BracketCapture(display, cam, exposure_times(args.exposures), response=response,
                          rectify=rectify, color_matrix=matrix, raw_only=raw_only)


def cmd_capture(args: argparse.Namespace) -> int:
    from .controller import ControllerError  # pyserial: a capture-only package

    check_device_options(args)
    check_out_dir("--out", args.out)
    rig = Rig.from_scene(args.scene)
    networks = args.networks or str(DEFAULT_NETWORKS)
    acquisition = load_adaptive(networks, rig, transfer=args.transfer)
    acquisition.check_resolution(args.resolution, "--resolution")  # before the first frame
    material = SVBRDF.load(args.simulate).resized(args.resolution) if args.simulate else None
    display, cam, response, matrix, ctl = _devices(args, rig, material)
    try:
        capture = _bracket(args, rig, display, cam, response, matrix)
        settings = {"scene": str(Path(args.scene).resolve()) if args.scene else "default",
                    "networks": str(Path(networks).resolve()), "resolution": args.resolution}
        if args.simulate:
            settings.update(simulate=str(Path(args.simulate).resolve()), spp=args.spp, seed=args.seed)
        session = CaptureSession(args.out, acquisition, capture, settings)
        session.run(resume=args.resume, progress=not args.quiet)
    except ControllerError as e:
        raise DeviceError(f"{e}; every frame so far is in {args.out}: fix the link and rerun with --resume") from e
    except KeyboardInterrupt:
        print(f"\nmitsvbrdf: interrupted; every frame so far is in {args.out}: rerun with --resume", file=sys.stderr)
        return 130
    finally:
        if ctl is not None:
            ctl.close()
    if session.recaptured:
        print(f"redone because the recorded files were missing or changed: {', '.join(session.recaptured)}")
    print(f"session complete in {args.out}: maps.png, maps.exr, raw/, radiance/, session.json")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    check_out_file("--out", args.out)
    if args.step != "intrinsics":
        check_device_options(args, exposures_needed=2 if args.step == "response" else 1)
        check_float("--albedo", args.albedo, 0.0, 1.0, low_open=True)
    scene = args.scene or str(DEFAULT_SCENE)
    args.scene = scene
    rig = Rig.from_scene(scene)
    if args.step == "intrinsics":
        return _calibrate_intrinsics(args, rig)
    targets = cal.calibration_targets(args.resolution, rig, args.albedo)
    display, cam, response, matrix, ctl = _devices(args, rig, targets["white"])
    if args.simulate:
        place = lambda t: display.place(targets[t])  # noqa: E731
    else:
        place = lambda t: input(f"put the {t} target on the sample, then press Enter ")  # noqa: E731
    try:
        # calibrating the response: the frames as they are
        bench = cal.Bench(_bracket(args, rig, display, cam, response, matrix, raw_only=args.step == "response"),
                          place)
        if args.step == "response":
            fit = cal.calibrate_camera_response(bench, rig.lcd_cells)
            write_camera_calibration(scene, args.out, response=fit)
            record = {"levels": fit.levels}
        elif args.step == "display":
            record = cal.calibrate_display(bench, rig, albedo=args.albedo)
            params = {k: record[k] for k in ("gamma", "decay_cos_power") if record[k] is not None}
            write_display_model(scene, args.out, intensity=tuple(record["intensity"]), **params)
        elif args.step == "color":
            fit = cal.calibrate_color(bench, rig)
            write_camera_calibration(scene, args.out, color_matrix=fit["matrix"])
            record = {"matrix": fit["matrix"].tolist(), "delta_e_max": float(fit["delta_e"].max()),
                      "delta_e_mean": float(fit["delta_e"].mean())}
        else:
            fit = cal.calibrate_lcd_pose(bench, rig)
            write_lcd_pose(scene, args.out, fit["lcd_to_world"])
            record = {"lcd_to_world": fit["lcd_to_world"].tolist(), "cells": fit["cells"], "rms_mm": fit["rms_mm"]}
    finally:
        if ctl is not None:
            ctl.close()
    print(json.dumps({"step": args.step, "scene": str(args.out), **record}, indent=2))
    return 0


def _calibrate_intrinsics(args, rig) -> int:
    if not args.views:
        raise MitsvbrdfError("calibrate intrinsics needs --views DIR of checkerboard photos")
    if not Path(args.views).is_dir():
        raise MitsvbrdfError(f"--views {args.views!r} is not a folder")
    check_float("--square", args.square, 0.0, low_open=True)
    try:
        inner = tuple(int(v) for v in args.inner.lower().split("x"))
    except ValueError:
        inner = ()
    if len(inner) != 2 or min(inner) < 2:
        raise MitsvbrdfError(f"--inner must be ROWSxCOLS inner corners, each >= 2, got {args.inner!r}")
    files = sorted(p for p in Path(args.views).iterdir() if p.suffix.lower() in imageio.READ_SUFFIXES)
    if len(files) < 3:
        raise MitsvbrdfError(f"{args.views}: need at least 3 checkerboard photos, found {len(files)}")
    points, size = [], None
    for f in files:
        img = imageio.read_image(f)
        img = img[..., :3].mean(-1) if img.ndim == 3 else img
        size = img.shape[:2]
        points.append(find_checkerboard_corners(img, inner))
    k, rms = calibrate_intrinsics(points, checkerboard_points(inner, args.square), size)
    write_camera_intrinsics(args.scene, args.out, k, size)
    print(json.dumps({"step": "intrinsics", "scene": str(args.out), "K": k.tolist(), "rms_px": rms,
                      "views": len(files)}, indent=2))
    return 0


def add_parsers(sub) -> None:
    c = sub.add_parser("capture", help="run the adaptive acquisition at the bench (or on the simulated rig)")
    c.add_argument("--scene", default=None, help="calibrated rig scene file (default: the package's default rig)")
    c.add_argument("--out", required=True, help="session folder (every frame is written as it arrives)")
    c.add_argument("--resume", action="store_true", help="continue the session in --out")
    c.add_argument("--networks", default="", help="networks.pt of stage2/finetune (default: the shipped weights)")
    c.add_argument("--transfer", default=DEFAULT_TRANSFER, choices=TRANSFER_MODES, help=TRANSFER_HELP)
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    add_device_options(c)
    c.set_defaults(func=cmd_capture)
    k = sub.add_parser("calibrate", help="calibrate the bench; writes the result into a copy of the scene file")
    k.add_argument("step", choices=["response", "display", "color", "geometry", "intrinsics"])
    k.add_argument("--scene", default=None, help="scene file to start from (default: the package's default rig)")
    k.add_argument("--out", required=True, help="the calibrated scene file to write")
    k.add_argument("--albedo", type=float, default=0.8, help="display: albedo of the white target (default 0.8)")
    k.add_argument("--views", default="", help="intrinsics: folder of checkerboard photos")
    k.add_argument("--inner", default="6x8", help="intrinsics: inner corners ROWSxCOLS (default 6x8)")
    k.add_argument("--square", type=float, default=0.005, help="intrinsics: square side in metres (default 0.005)")
    add_device_options(k)
    k.set_defaults(func=cmd_calibrate)
