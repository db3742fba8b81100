"""The whole training chain in one time budget: ``mitsvbrdf train-chain CHAIN.toml``.

A chain file lists stage configs in order; each stage starts from the previous one's export, and
one total time budget is split between them by configured shares::

    out = "runs/chain-small"        # stage k trains in OUT/<k>-<stage>, e.g. OUT/1-init
    time_budget = "2h"              # total seconds of training (or --time-budget on the command line)
    set = ["data.size=64"]          # overrides applied to every stage

    [[stages]]
    config = "init-small.toml"      # relative to the chain file
    share = 0.1                     # of the total budget
    set = ["train.lr=1e-3"]         # overrides of this stage only

Budget: when stage k starts, it gets ``share_k / sum(share_k..share_n)`` of the budget not yet
spent by the stages before it (their own recorded loop time), so time a stage does not use (it
reached ``train.steps`` first) goes to the later ones. Each stage's ``train.steps`` is an upper
bound only (a stage's cosine schedule follows its time, see :mod:`.trainer`). A stage always trains
at least one step, so a chain whose early stages overran its budget still ends with an export.

Resumable at any point: a finished stage (its checkpoint says so) is skipped, an interrupted one
continues from its checkpoint, so after a crash or SIGTERM the same command picks up where the chain
stopped. At the end the last stage's export is copied to ``OUT/networks.pt`` and ``OUT/chain.json``
records, per stage, the steps, loop time and last losses, with the command, the commit and the
chain's wall time (the provenance a shipped export needs).
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import torch

from .config import ConfigError, load_config, parse_duration, parse_override
from .trainer import Trainer

#: ``train.steps`` of a budgeted stage whose config does not cap it: the budget ends it.
UNCAPPED_STEPS = 10_000_000


@dataclass
class ChainStage:
    config: Path
    share: float
    overrides: list[str] = field(default_factory=list)


@dataclass
class Chain:
    out: Path
    time_budget: float
    stages: list[ChainStage]
    overrides: list[str] = field(default_factory=list)
    source: Path | None = None


def _strings(value, where: str) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{where}: expected a list of 'key.path=value' strings")
    return list(value)


def load_chain(path: str | Path, *, time_budget: str | float | None = None, out: str | Path | None = None) -> Chain:
    """Read a chain file (module docstring); ``time_budget`` and ``out`` replace the file's."""
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{p}: no such chain file")
    try:
        t = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{p}: not valid TOML ({e})") from None
    unknown = sorted(set(t) - {"out", "time_budget", "set", "stages"})
    if unknown:
        raise ConfigError(f"{p}: unknown key {unknown[0]!r} (known: out, time_budget, set, stages)")
    budget = time_budget if time_budget is not None else t.get("time_budget")
    if budget is None:
        raise ConfigError(f"{p}: time_budget: missing (in the file or --time-budget)")
    stages = []
    raw = t.get("stages")
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{p}: stages: expected one or more [[stages]] tables")
    for i, s in enumerate(raw):
        where = f"{p}: stages[{i}]"
        extra = sorted(set(s) - {"config", "share", "set"}) if isinstance(s, dict) else []
        if not isinstance(s, dict) or "config" not in s or extra:
            raise ConfigError(f"{where}: needs config (a file) and share, optionally set"
                              + (f"; unknown key {extra[0]!r}" if extra else ""))
        share = s.get("share", 0)
        if isinstance(share, bool) or not isinstance(share, (int, float)) or not share > 0:
            raise ConfigError(f"{where}.share: must be a number > 0, got {share!r}")
        cfg = (p.parent / s["config"]).resolve()
        if not cfg.exists():
            raise ConfigError(f"{where}.config: {cfg} does not exist")
        stages.append(ChainStage(cfg, float(share), _strings(s.get("set", []), f"{where}.set")))
    return Chain(Path(out if out is not None else t.get("out", "runs/chain")), parse_duration(budget), stages,
                 _strings(t.get("set", []), f"{p}: set"), p)


def stage_dir(chain: Chain, k: int) -> Path:
    return chain.out / f"{k + 1}-{load_config(chain.stages[k].config).stage}"


def _checkpoint_state(folder: Path) -> dict:
    """{"elapsed", "finished", "step"} of a stage's checkpoint (zeros when there is none)."""
    path = folder / "checkpoint.pt"
    if not path.exists():
        return {"elapsed": 0.0, "finished": False, "step": 0}
    ck = torch.load(path, map_location="cpu", weights_only=True)
    return {"elapsed": float(ck.get("elapsed", 0.0)), "finished": bool(ck.get("finished", False)),
            "step": int(ck["step"]), "last": ck["history"][-1] if ck.get("history") else {}}


def _command() -> str:
    """The command line as a user would type it, without the machine's paths: ``python -m`` gives
    argv[0] as the absolute path of the package's __main__.py, recorded as the package's name
    (``mitsvbrdf ...`` for the CLI); a script is recorded by its file name."""
    argv0 = Path(sys.argv[0]) if sys.argv and sys.argv[0] else Path("python")
    prog = argv0.parent.name if argv0.name == "__main__.py" else argv0.name
    return " ".join([prog, *(shlex.quote(a) for a in sys.argv[1:])])


def _commit() -> str:
    try:
        root = Path(__file__).resolve().parents[2]
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return (rev + ("+changes" if dirty else "")) if rev else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run_chain(chain: Chain, *, progress: bool = True, overwrite: bool = False, extra: list[str] | None = None,
              stop_after: int | None = None) -> dict:
    """Train the chain's stages in order within its budget (module docstring); returns the record
    written to ``OUT/chain.json``. ``extra`` overrides apply to every stage after the file's;
    ``stop_after`` (tests) stops the chain as if killed after that many steps of the stage it is in.
    Raises :class:`TrainingInterrupted` (after checkpointing) when SIGINT/SIGTERM stops a stage."""
    if overwrite and chain.out.exists():
        shutil.rmtree(chain.out)
    chain.out.mkdir(parents=True, exist_ok=True)
    wall0 = time.perf_counter()
    record = {"command": _command(), "commit": _commit(), "chain": str(chain.source or ""),
              "time_budget_s": chain.time_budget, "stages": []}
    previous: Path | None = None
    spent = 0.0  # loop time of the stages before this one (all finished when it is reached)
    for k, st in enumerate(chain.stages):
        folder = stage_dir(chain, k)
        state = _checkpoint_state(folder)
        left = max(chain.time_budget - spent, 0.0)
        share = st.share / sum(s.share for s in chain.stages[k:])
        budget = max(left * share, state["elapsed"]) if state["finished"] else left * share
        overrides = [*chain.overrides, *st.overrides, *(extra or []), f'out="{folder}"',
                     f"train.time_budget={max(budget, 1e-3)}"]
        if previous is not None:
            overrides.append(f'pretrained.networks="{previous / "networks.pt"}"')
        cfg = load_config(st.config, overrides)
        capped = any(parse_override(o)[0] == ["train", "steps"] for o in [*chain.overrides, *st.overrides,
                                                                          *(extra or [])])
        if not capped:
            cfg.train.steps = UNCAPPED_STEPS
        if not state["finished"]:
            if budget <= 0:  # the stages before overran by their last step: this one still trains one
                print(f"train-chain: no time left for stage {k + 1} ({cfg.stage}) after {spent:.0f} s of "
                      f"{chain.time_budget:.0f} s; it trains one step", file=sys.stderr)
            trainer = Trainer(cfg, resume=(folder / "checkpoint.pt").exists(), progress=progress,
                              stop_after=stop_after)
            trainer.run()
            if not trainer.finished:  # stop_after: as if killed
                return record
            state = _checkpoint_state(folder)
        record["stages"].append({"stage": cfg.stage, "config": st.config.name, "out": str(folder), "share": st.share,
                                 "budget_s": round(budget, 1), "steps": state["step"],
                                 "elapsed_s": round(state["elapsed"], 1), "last": state.get("last", {})})
        spent += state["elapsed"]
        previous = folder
    shutil.copyfile(previous / "networks.pt", chain.out / "networks.pt")
    record["wall_s_this_invocation"] = round(time.perf_counter() - wall0, 1)
    record["training_s"] = round(sum(s["elapsed_s"] for s in record["stages"]), 1)
    (chain.out / "chain.json").write_text(json.dumps(record, indent=1))
    return record


__all__ = ["Chain", "ChainStage", "load_chain", "run_chain", "stage_dir", "UNCAPPED_STEPS"]
