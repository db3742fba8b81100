"""Training configuration: TOML files -> validated dataclasses (data, not code).

Layout (every key optional except ``stage``; defaults below)::

    stage = "stage1"              # init | stage1 | stage2 | finetune | fixed
    seed = 0
    out = "runs/stage1"           # relative paths are relative to the current directory
    scene = ""                    # rig scene file; "": the package's default rig

    [data]     source = "procedural" | "strips" | "folders"; root; size; length; families;
               bump = [lo, hi] (procedural relief multiplier, log-uniform per material);
               dark_metals (fraction of procedural materials with dark pure metals, F0 0.03-0.3);
               crop_from (0: materials at ``size``; N > size: materials at N px, each step's batch
               a random size x size window of them, rendered where it sits: Rig.window)
    [render]   method = "mitsuba" | "ltc" | "reference"; spp; [render.noise] shot, read, bits;
               [render.integrator] options of the scene's ``importance`` integrator for the training
               captures (method "mitsuba"; e.g. ltc_grid = 8), written into a copy of the scene in
               ``out`` (scene.xml); what is modelled stays the scene file's
    [model]    the stage's own options (see mitsvbrdf.training.stages: *Model dataclasses)
    [loss]     the stage's loss weights (*Loss dataclasses)
    [train]    steps, batch, lr, lr_min, weight_decay, grad_clip, checkpoint_every, log_every, device,
               time_budget (seconds of training; 0: none. With a budget the cosine schedule runs on
               the elapsed fraction of it, and steps is only an upper bound)
    [pretrained]  networks = "runs/init/networks.pt"  (an earlier stage's export);
                  warm_start = "mitsvbrdf/weights/networks.pt"  (an export the networks this stage
                  builds from scratch start from, where it has them);
                  scratch = ["initializer"]  (networks that warm start leaves out)

Shared bases: ``extends = "base/small.toml"`` (or a list of files, applied in order) at the top
level reads those configs first, relative to the including file; a base may extend others in turn.
Tables merge key by key and the including file wins over its bases (a later base over an earlier
one); any other value, a list included, is replaced whole. The merged table is what is validated,
what ``--set`` overrides apply to and what a run records (:func:`config_table`), so a run's
``config.json`` holds every value and reproduces it without the bases. A missing base, a cycle
or a file that is not TOML is refused naming the chain of files: ``a.toml -> base/b.toml: no
such config file``.

Procedural materials are drawn by global index from the generator seeded with ``seed``; the
evaluation's held-out set uses seeds >= 1_000_000 (:data:`TEST_SEED_BASE`), never used here.
Errors name the offending key path: ``train.stpes: unknown key (did you mean 'steps'?)``.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import math
import os
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import MitsvbrdfError
from ..scene_xml import INTEGRATOR_OPTION_TAGS

TEST_SEED_BASE = 1_000_000


class ConfigError(MitsvbrdfError):
    """A training configuration that cannot be used; the message names the key."""


@dataclass
class DataConfig:
    source: str = "procedural"
    root: str = ""
    size: int = 64
    length: int = 100_000
    families: list[str] = field(default_factory=list)
    # procedural relief multiplier range [lo, hi], log-uniform per material ([1, 1]: the
    # generator's own relief); see mitsvbrdf.data.procedural.generate
    bump: list[float] = field(default_factory=lambda: [1.0, 1.0])
    # fraction of procedural materials whose pure-metal texels get a dark F0 (oxidised, anodised:
    # mitsvbrdf.data.procedural.DARK_METAL_F0); 0 keeps the stream as it was
    dark_metals: float = 0.0
    # 0: the materials are made at ``size``. N > size: they are made (or loaded) at N px and every
    # step trains on one random size x size window of them, the same for the batch, rendered with
    # the rig of that window (Rig.window), so each texel keeps its light and view directions: the
    # networks learn N px texels at the cost of size px steps (crops against reduced materials)
    crop_from: int = 0


@dataclass
class NoiseConfig:
    shot: float = 0.0      # photons per unit radiance at full exposure is 1 / shot (0: no shot noise)
    read: float = 0.0      # read-noise standard deviation, in units of the white level
    bits: int = 0          # quantisation bits (0: none)
    white: float = 1.0     # radiance mapped to the sensor's white level


@dataclass
class RenderConfig:
    method: str = "mitsuba"
    spp: int = 4
    ltc_mode: str = "exact"   # method = "ltc": "exact" (every LCD cell) or "prefiltered" (the paper's)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    # method = "mitsuba": integrator options over the scene file's (plugins/importance_integrator.py),
    # e.g. {ltc_grid = 8}: the estimator of the training captures, not what they model
    integrator: dict[str, Any] = field(default_factory=dict)


@dataclass
class TrainConfig:
    steps: int = 200
    batch: int = 4
    lr: float = 2e-4
    lr_min: float = 0.0
    weight_decay: float = 0.0
    grad_clip: float = 1.0
    checkpoint_every: int = 50
    log_every: int = 10
    device: str = "auto"
    time_budget: float = 0.0


@dataclass
class PretrainedConfig:
    networks: str = ""
    # networks.pt whose networks start those this stage would build from scratch, where it has them
    # (continuing a chain from an export: G_sc of stage 2 from the shipped weights)
    warm_start: str = ""
    # networks the warm start leaves out: built from the config and trained from scratch, e.g. a
    # wider initializer under the export's L_0 (["initializer"] with model.train_l0 = false)
    scratch: list[str] = field(default_factory=list)


@dataclass
class Config:
    stage: str
    seed: int = 0
    out: str = "runs/default"
    scene: str = ""
    data: DataConfig = field(default_factory=DataConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    model: Any = None
    loss: Any = None
    train: TrainConfig = field(default_factory=TrainConfig)
    pretrained: PretrainedConfig = field(default_factory=PretrainedConfig)


def _type_ok(value: Any, tp: Any) -> bool:
    origin = typing.get_origin(tp)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if origin is dict:
        key, inner = typing.get_args(tp) or (str, Any)
        return isinstance(value, dict) and all(_type_ok(k, key) and (inner is Any or _type_ok(v, inner))
                                               for k, v in value.items())
    if origin is list:
        (inner,) = typing.get_args(tp) or (Any,)
        return isinstance(value, list) and all(inner is Any or _type_ok(v, inner) for v in value)
    if tp is Any:
        return True
    return isinstance(value, tp)


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp)).replace("typing.", "")


def build(cls: type, table: dict, path: str) -> Any:
    """Dataclass ``cls`` from a TOML table; unknown keys and wrong types raise ConfigError."""
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: expected a table, got {type(table).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in table:
        if key not in fields:
            close = difflib.get_close_matches(key, list(fields), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(fields)})"
            raise ConfigError(f"{path}.{key}: unknown key{hint}".lstrip("."))
    kwargs = {}
    for name, f in fields.items():
        if name not in table:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{path}.{name}: missing required key".lstrip("."))
            continue
        value, tp = table[name], hints[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = build(tp, value, f"{path}.{name}")
        elif not _type_ok(value, tp):
            raise ConfigError(f"{path}.{name}: expected {_type_name(tp)}, got {type(value).__name__} "
                              f"({value!r})".lstrip("."))
        else:
            kwargs[name] = float(value) if tp is float else value
    return cls(**kwargs)


def parse_duration(text: str | float | int) -> float:
    """A duration in seconds from ``"2h"``, ``"90m"``, ``"1h30m"``, ``"45s"`` or a number of seconds."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        seconds = float(text)
    else:
        import re

        raw = str(text).strip().lower()
        parts = re.fullmatch(r"(?:(\d+(?:\.\d+)?)h)?(?:(\d+(?:\.\d+)?)m)?(?:(\d+(?:\.\d+)?)s?)?", raw)
        if not raw or parts is None:
            raise ConfigError(f"time budget {text!r}: expected e.g. 2h, 90m, 1h30m, 45s or seconds")
        seconds = sum(float(v) * u for v, u in zip(parts.groups(), (3600.0, 60.0, 1.0)) if v)
    if not math.isfinite(seconds) or seconds <= 0:
        raise ConfigError(f"time budget {text!r}: must be a positive duration")
    return seconds


def parse_override(text: str) -> tuple[list[str], Any]:
    """``train.steps=10`` -> (["train", "steps"], 10); values are parsed as TOML."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like key.path=value")
    key, raw = text.split("=", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # a bare word: a string
    return key.strip().split("."), value


def load_config(path: str | Path | None = None, overrides: list[str] | None = None,
                table: dict | None = None) -> Config:
    """Read and validate a config file (its ``extends`` resolved, :func:`read_table`) or a ready
    ``table`` (which cannot extend), then apply ``overrides``."""
    from .stages import STAGES

    table = read_table(path) if table is None else copy.deepcopy(table)
    for o in overrides or []:
        keys, value = parse_override(o)
        node = table
        for k in keys[:-1]:
            node = node.setdefault(k, {})
        node[keys[-1]] = value
    if "extends" in table:  # bases are relative to a file: a ready table or an override has none
        raise ConfigError("extends: only a config file can extend others (its bases are relative to it), "
                          "not a ready table or a --set")
    stage = table.get("stage")
    if stage not in STAGES:
        raise ConfigError(f"stage: must be one of {', '.join(STAGES)}, got {stage!r}")
    model, loss = table.pop("model", {}), table.pop("loss", {})
    cfg = build(Config, table, "")
    cfg.model = build(STAGES[stage].Model, model, "model")
    cfg.loss = build(STAGES[stage].Loss, loss, "loss")
    _check_values(cfg)
    return cfg


def read_table(path: str | Path) -> dict:
    """The table of config file ``path`` with its ``extends`` resolved (module docstring): the bases'
    tables merged in order, then the file's own over them; no ``extends`` key is left."""
    return _read_extending(Path(path), ())


def _read_extending(path: Path, including: tuple[Path, ...]) -> dict:
    trail = " -> ".join(str(p) for p in (*including, path))
    if path.resolve() in {p.resolve() for p in including}:
        raise ConfigError(f"{trail}: extends cycle")
    if not path.exists():
        raise ConfigError(f"{trail}: no such config file")
    try:
        table = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{trail}: not valid TOML ({e})") from None
    except OSError as e:
        raise ConfigError(f"{trail}: cannot be read ({e.strerror or e})") from None
    bases = table.pop("extends", [])
    if isinstance(bases, str):
        bases = [bases]
    if not isinstance(bases, list) or not all(isinstance(b, str) for b in bases):
        raise ConfigError(f"{trail}: extends: expected a file name or a list of file names, got {bases!r}")
    merged: dict = {}
    for base in bases:
        base_path = Path(os.path.normpath(path.parent / base))
        merged = _merge(merged, _read_extending(base_path, (*including, path)))
    return _merge(merged, table)


def _merge(base: dict, over: dict) -> dict:
    """``over`` on ``base``: tables merge key by key, any other value (a list too) replaces."""
    merged = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def _check_values(cfg: Config) -> None:
    for key, value in _leaves(config_table(cfg)):  # TOML has inf and nan literals
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{key}: must be a finite number, got {value}")
    checks = [(cfg.data.source in ("procedural", "strips", "folders"), "data.source", "procedural, strips or folders"),
              (cfg.render.method in ("mitsuba", "ltc", "reference"), "render.method", "mitsuba, ltc or reference"),
              (cfg.render.ltc_mode in ("exact", "prefiltered"), "render.ltc_mode", "exact or prefiltered"),
              (cfg.train.device in ("auto", "cpu", "cuda"), "train.device", "auto, cpu or cuda"),
              (cfg.train.steps >= 1, "train.steps", ">= 1"), (cfg.train.batch >= 1, "train.batch", ">= 1"),
              (cfg.train.checkpoint_every >= 1, "train.checkpoint_every", ">= 1"),
              (cfg.train.log_every >= 1, "train.log_every", ">= 1"),
              (cfg.data.size >= 8 and cfg.data.size % 8 == 0, "data.size", "a positive multiple of 8"),
              (cfg.data.length >= 1, "data.length", ">= 1"),
              (cfg.data.crop_from == 0 or (cfg.data.crop_from > cfg.data.size and cfg.data.crop_from % 8 == 0),
               "data.crop_from", "0 (off) or a multiple of 8 larger than data.size (the materials the windows are "
               "cut from)"),
              (len(cfg.data.bump) == 2 and 0 < cfg.data.bump[0] <= cfg.data.bump[1], "data.bump",
               "a range [lo, hi] with 0 < lo <= hi"),
              (cfg.data.source == "procedural" or cfg.data.bump == [1.0, 1.0], "data.bump",
               "[1, 1] unless data.source = 'procedural' (loaded maps keep their own relief)"),
              (0.0 <= cfg.data.dark_metals <= 1.0, "data.dark_metals", "a fraction in [0, 1]"),
              (cfg.data.source == "procedural" or cfg.data.dark_metals == 0, "data.dark_metals",
               "0 unless data.source = 'procedural' (loaded maps keep their own albedos)"),
              (cfg.train.lr_min >= 0, "train.lr_min", ">= 0"), (cfg.train.weight_decay >= 0, "train.weight_decay", ">= 0"),
              (cfg.train.grad_clip >= 0, "train.grad_clip", ">= 0 (0: no clipping)"),
              (cfg.render.noise.shot >= 0, "render.noise.shot", ">= 0"),
              (cfg.render.noise.read >= 0, "render.noise.read", ">= 0"),
              (cfg.render.noise.bits >= 0, "render.noise.bits", ">= 0"),
              (cfg.render.noise.white > 0, "render.noise.white", "> 0"),
              (cfg.render.spp >= 1, "render.spp", ">= 1"), (cfg.train.lr > 0, "train.lr", "> 0"),
              (cfg.train.time_budget >= 0, "train.time_budget", ">= 0 seconds (0: no budget)")]
    for ok, key, want in checks:
        if not ok:
            raise ConfigError(f"{key}: must be {want}")
    weights = getattr(cfg.loss, "map_weights", None)
    if weights is not None:
        from ..losses import map_weight_channels

        try:
            map_weight_channels(weights)
        except ValueError as e:
            raise ConfigError(f"loss.map_weights: {e}") from None
    for name, value in cfg.render.integrator.items():
        if type(value) not in INTEGRATOR_OPTION_TAGS:
            raise ConfigError(f"render.integrator.{name}: must be a string, boolean, integer or float, got {value!r}")
    if cfg.render.integrator and cfg.render.method != "mitsuba":
        raise ConfigError(f"render.integrator: integrator options need render.method = 'mitsuba', "
                          f"got {cfg.render.method!r}")
    if cfg.data.source != "procedural" and not cfg.data.root:
        raise ConfigError(f"data.root: needed for data.source = {cfg.data.source!r}")


def _leaves(t: Any, prefix: str = ""):
    """(dotted key, value) of every non-table value, list items included."""
    if isinstance(t, dict):
        for k, v in t.items():
            yield from _leaves(v, f"{prefix}{k}.")
    elif isinstance(t, list):
        for i, v in enumerate(t):
            yield from _leaves(v, f"{prefix[:-1]}[{i}].")
    else:
        yield prefix[:-1], t


def config_table(cfg: Config) -> dict:
    """The config as plain data (for checkpoints and the run record)."""
    return dataclasses.asdict(cfg)

