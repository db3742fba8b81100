"""Path-traced rendering through the scene file's own Mitsuba plugins, differentiable from torch.

``render(..., method="mitsuba", spp=N)`` loads the scene once per (scene file, variant), then for
every call swaps the material maps and patterns into the loaded scene in place
(``mi.traverse`` parameters, no scene reload) and runs the ``importance`` integrator's
texel-grid renderer: (B, P, 3, H, W), all P patterns from one set of light samples. Gradients w.r.t.
patterns and maps flow back to torch through ``dr.wrap``. CPU tensors use ``llvm_ad_rgb``, CUDA
tensors ``cuda_ad_rgb``. The seed is passed as an opaque value, so new data and new seeds reuse the
compiled kernels; only a new resolution, spp or pattern count compiles new ones. Without gradients
the integrator replays the kernels it recorded for the configuration, tracing nothing (its
``freeze`` option; :func:`release_scenes` says when that cannot work).

The integrator's options in the scene file decide the estimator (sampler, control variate; see
plugins/importance_integrator.py). With a control variate, its closed-form part and per-texel
coefficients are computed here in torch (:mod:`.control_variate`), handed to the integrator,
which estimates only the residual, and added back: one set of numbers for both halves. In mode
"ltc-grid" torch computes only the patterns' grid radiance, and the integrator's kernels both
halves.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..checks import SEED_MAX, check_int, check_seed
from ..errors import MitsvbrdfError, PatternError, SceneError
from ..rig import Rig
from .control_variate import control_variate

_SCENES: dict[tuple[str, str], tuple] = {}


def variant_for(device: torch.device) -> str:
    """The Mitsuba variant that renders tensors on ``device``: Dr.Jit shares their memory."""
    return "cuda_ad_rgb" if device.type == "cuda" else "llvm_ad_rgb"


def load_scene(source: str, variant: str):
    """The loaded Mitsuba scene, its parameters and integrator for a scene file (cached)."""
    import mitsvbrdf_plugins

    # Every call: ``mi``'s types follow the current variant, which other code may have switched
    # (e.g. to scalar_rgb) since the scene was loaded; the plugins must run in the scene's.
    mi = mitsvbrdf_plugins.register(variant)
    key = (source, variant)
    if key not in _SCENES:
        try:
            scene = mi.load_file(source)
        except RuntimeError as e:
            raise SceneError(f"{source}: Mitsuba cannot load the scene ({e})") from e
        integrator = scene.integrator()
        if not isinstance(integrator, mitsvbrdf_plugins.plugin_class("importance", variant)):
            raise SceneError(f"{source}: the scene's integrator must be type=\"importance\" for method='mitsuba'")
        _SCENES[key] = (mi, scene, mi.traverse(scene), integrator)
    return _SCENES[key]


def release_scenes(keep: str | None = None) -> int:
    """Drop the loaded scenes (all, or all but those of the scene file ``keep``) from the cache, so
    that Mitsuba frees them once nothing else holds them; returns how many were dropped. A frozen
    render's inputs include every emitter, shape and sensor of every scene alive in the process
    (the ``freeze`` option of plugins/importance_integrator.py): with other scenes rendering in
    between, a render records its kernels again instead of replaying them."""
    import gc

    drop = [key for key in _SCENES if keep is None or key[0] != str(keep)]
    for key in drop:
        del _SCENES[key]
    if drop:
        gc.collect()  # the plugins' Python objects hold the scenes' Mitsuba objects in cycles
    return len(drop)


def _place_sample(params, rig: Rig) -> None:
    """Move the loaded scene's sample rectangle where ``rig`` has it (a window of the sample,
    :meth:`Rig.window`, or back to the file's); untouched, and no scene update, when it is there."""
    import drjit as dr

    want = rig.sample_to_world()
    have = params["sample.to_world"]
    if not np.array_equal(np.array(have.matrix.numpy(), dtype=np.float32).reshape(4, 4), want.astype(np.float32)):
        placed = type(have)(want.tolist())
        # Opaque: as literals the matrix entries were compiled into the render kernel, and every
        # new window of a training run compiled it again (several renders' time each).
        dr.make_opaque(placed)
        params["sample.to_world"] = placed
        params.update()


def integrator_control_variate(svbrdf, patterns: Tensor, rig: Rig, integrator):
    """The closed-form part (:func:`control_variate`) with the options of the scene's ``importance``
    integrator, for patterns (B, P, 3, h, w); None where it has none (plain Monte Carlo)."""
    if integrator.control_variate == "none":
        return None
    return control_variate(svbrdf, patterns, rig, mode=integrator.control_variate,
                           blocks=integrator.cv_blocks, ltc_min_roughness=integrator.ltc_min_roughness,
                           ltc_min_cos_view=integrator.ltc_min_cos_view, ltc_grid=integrator.ltc_grid,
                           ltc_cells_min_roughness=integrator.ltc_cells_min_roughness,
                           ltc_window=integrator.ltc_window,
                           ltc_window_min_roughness=integrator.ltc_window_min_roughness)


def render_mitsuba(svbrdf, patterns: Tensor, rig: Rig, *, spp: int = 64, seed: int = 0) -> Tensor:
    """Render B materials under P patterns with the scene's plugins; see the module docstring.

    Args:
        svbrdf: maps (B, C, H, W) on the CPU (llvm) or a CUDA device (cuda).
        patterns: drive values (P, 3, h, w) or (B, P, 3, h, w), on the maps' device.
        rig: the rig whose ``source`` scene file is rendered (its display model is the file's).
        spp: samples per texel; seed: sampler seed (material b uses seed + b).
    Returns:
        (B, P, 3, H, W) float32 radiance, differentiable w.r.t. patterns and maps.
    """
    check_int("spp", spp, 1)
    check_seed("seed", seed, svbrdf.batch_size)
    lanes = svbrdf.batch_size * svbrdf.resolution[0] * svbrdf.resolution[1] * spp
    if lanes > SEED_MAX:  # one UInt32 lane index per (material, texel, sample)
        raise MitsvbrdfError(f"spp {spp} x {svbrdf.batch_size} x {svbrdf.resolution[0]} x {svbrdf.resolution[1]} "
                             f"texels is {lanes} samples, more than one pass can index (2^32 - 1); lower spp")
    device = svbrdf.device
    if patterns.device != device:
        raise PatternError(f"patterns are on {patterns.device}, the maps on {device}; put both on one device")
    if patterns.dtype != torch.float32:
        raise PatternError(f"patterns must be float32, got {patterns.dtype}")
    rig.check_patterns(patterns)
    if not Path(rig.source).is_file():
        raise ValueError(f"method='mitsuba' needs a rig read from a scene file, got source {rig.source!r}")
    mi, scene, params, integrator = load_scene(str(rig.source), variant_for(device))
    _place_sample(params, rig)
    import drjit as dr  # after load_scene: the backend must choose libLLVM before drjit loads

    B = svbrdf.batch_size
    H, W = svbrdf.resolution
    if patterns.ndim == 4:
        patterns = patterns.unsqueeze(0).expand(B, *patterns.shape)
    elif patterns.shape[0] != B:
        raise PatternError(f"per-material patterns have batch {patterns.shape[0]}, the SVBRDF has {B}")

    cv = integrator_control_variate(svbrdf, patterns, rig, integrator)

    @dr.wrap(source="torch", target="drjit")
    def batch(normal, diffuse, roughness, specular, drive, seed_value, block_rad, coeffs, lobe_grid, grid_rad, table,
              cell_rad):
        params["sample.bsdf.normal"] = normal
        params["sample.bsdf.diffuse"] = diffuse
        params["sample.bsdf.roughness"] = roughness
        params["sample.bsdf.specular"] = specular
        params["lcd.emitter.data"] = drive
        params.update()
        control = None if cv is None else (block_rad.array, coeffs.array,
                                           None if cv.lobe_grid is None else lobe_grid.array,
                                           None if cv.grid_radiance is None else grid_rad.array,
                                           None if cv.ltc_table is None else table.array,
                                           None if cv.cell_radiance is None else cell_rad.array)
        return integrator.render_texels(scene, (H, W), spp, seed_value, batch=B, control=control)

    def stacked(t):  # (B, C, H, W) -> (B * H, W, C): the plugin's layout, materials along rows
        return t.permute(0, 2, 3, 1).reshape(B * H, W, t.shape[1]).contiguous()

    P = patterns.shape[1]
    empty = torch.zeros(1, device=device)
    images = batch(stacked(svbrdf.normal), stacked(svbrdf.diffuse), stacked(svbrdf.roughness),
                   stacked(svbrdf.specular), patterns.reshape(B * P, *patterns.shape[2:]).contiguous(),
                   dr.opaque(mi.UInt32, seed),
                   *(empty if t is None else t.contiguous() for t in
                     ((None,) * 6 if cv is None else
                      (cv.block_radiance, cv.texel, cv.lobe_grid, cv.grid_radiance, cv.ltc_table, cv.cell_radiance))))
    images = images.reshape(B, P, 3, H, W)
    return images if cv is None or cv.known is None else images + cv.known
