"""Saving and loading networks with what rebuilds them: class name, constructor arguments, weights."""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from ..errors import MitsvbrdfError
from ..relight import FlashLight
from .initializer import Initializer, LearnedPattern, PatternSet
from .lighting import LightingPredictor
from .point import PointPredictor
from .svbrdf_net import SVBRDFPredictor


class NetworkFileError(MitsvbrdfError):
    """A network file that is missing, corrupt, or made for another architecture."""


def registry() -> dict[str, type[nn.Module]]:
    return {c.__name__: c for c in (Initializer, LearnedPattern, PatternSet, LightingPredictor, PointPredictor,
                                   SVBRDFPredictor, FlashLight)}


def network_record(net: nn.Module) -> dict:
    """{"class", "config", "state"} of a network built by this package."""
    return {"class": type(net).__name__, "config": dict(net.config), "state": net.state_dict()}


def network_from_record(rec: dict, where: str = "record") -> nn.Module:
    """Rebuild a network from :func:`network_record`; clear errors for foreign records."""
    if not isinstance(rec, dict) or not {"class", "config", "state"} <= set(rec):
        raise NetworkFileError(f"{where}: not a mitsvbrdf network (needs class, config and state)")
    cls = registry().get(rec["class"])
    if cls is None:
        raise NetworkFileError(f"{where}: unknown network class {rec['class']!r}; known: {', '.join(registry())}")
    net = cls(**rec["config"])
    try:
        net.load_state_dict(rec["state"])
    except RuntimeError as e:
        raise NetworkFileError(f"{where}: weights do not fit a {rec['class']}({rec['config']}): "
                               f"{str(e).splitlines()[0]}") from e
    return net


def write_network_file(path: str | Path, contents: dict) -> Path:
    """Write a network file (one record, or a stage export {name: record, ...}) atomically: into a
    temporary file beside it, then renamed, so a crash never leaves half a file under its name."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(contents, tmp)
    tmp.replace(path)
    return path


def save_network(path: str | Path, net: nn.Module) -> None:
    write_network_file(path, network_record(net))


def read_network_file(path: str | Path, what: str = "network", hint: str = ""):
    """The contents of a network file (one record, or {name: record} for a stage's export), with
    clear errors for a missing or unreadable file."""
    path = Path(path)
    if not path.exists():
        raise NetworkFileError(f"{path}: no such {what} file{hint}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch's messages run over many lines: the first says what went wrong
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise NetworkFileError(f"{path}: cannot read a {what} from it ({type(e).__name__}: {first})") from e


def load_network(path: str | Path, expect: type[nn.Module] | None = None) -> nn.Module:
    """Load a network file; ``expect`` checks its class (a G_sc file where a G_l belongs fails)."""
    net = network_from_record(read_network_file(path), str(path))
    if expect is not None and not isinstance(net, expect):
        raise NetworkFileError(f"{path}: holds a {type(net).__name__}, expected a {expect.__name__}")
    return net


def parameter_count(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


def average_exports(paths: list[str | Path]) -> dict:
    """The uniform weight average of stage exports (``{name: network record, ...}``, e.g. runs that
    continued one export under different seeds or losses: a "model soup").

    Every file must hold the same networks, each of the same class and constructor arguments, and
    the same non-network entries (the acquisition settings); floating-point weights are averaged,
    every other tensor (counters) must agree. Averaging only helps where the runs started from one
    set of weights and stayed in its basin; networks a run kept frozen come out unchanged.
    Returns the averaged export, ready for ``torch.save``."""
    if len(paths) < 2:
        raise ValueError(f"averaging needs at least two exports, got {len(paths)}")
    exports = [read_network_file(p, "stage export") for p in paths]
    first, where = exports[0], str(paths[0])
    for path, ex in zip(paths[1:], exports[1:]):
        if not isinstance(ex, dict) or set(ex) != set(first):
            raise NetworkFileError(f"{path}: holds {sorted(ex) if isinstance(ex, dict) else type(ex).__name__}, "
                                   f"{where} holds {sorted(first)}: not exports of one chain")
    out = {}
    for name, rec in first.items():
        if not _is_network_record(rec):
            for path, ex in zip(paths[1:], exports[1:]):
                if ex[name] != rec:
                    raise NetworkFileError(f"{path}: its {name!r} ({ex[name]!r}) differs from {where}'s ({rec!r})")
            out[name] = rec
            continue
        for path, ex in zip(paths[1:], exports[1:]):
            other = ex[name]
            if not isinstance(other, dict) or (other.get("class"), other.get("config")) != (rec["class"], rec["config"]):
                raise NetworkFileError(f"{path}: its {name!r} is not a {rec['class']}({rec['config']}) as in {where}")
            if set(other["state"]) != set(rec["state"]):
                raise NetworkFileError(f"{path}: the weights of its {name!r} have other names than {where}'s")
        state = {}
        for key, t in rec["state"].items():
            ts = [ex[name]["state"][key] for ex in exports]
            if any(x.shape != t.shape for x in ts):
                raise NetworkFileError(f"{name}.{key}: shapes {[tuple(x.shape) for x in ts]} differ between the exports")
            if t.is_floating_point():
                state[key] = (torch.stack([x.double() for x in ts]).mean(0)).to(t.dtype)
            elif all(torch.equal(x, t) for x in ts):
                state[key] = t
            else:
                raise NetworkFileError(f"{name}.{key}: a non-float tensor that differs between the exports")
        out[name] = {"class": rec["class"], "config": rec["config"], "state": state}
        network_from_record(out[name], f"the average of {name!r}")  # it must still build
    return out


def _is_network_record(rec) -> bool:
    return isinstance(rec, dict) and {"class", "config", "state"} <= set(rec)


def replace_networks(base: str | Path, donor: str | Path, names: list[str]) -> dict:
    """``base``'s export with the networks ``names`` taken from ``donor``'s (e.g. an initializer
    trained further on its own, put back in front of the G_l and G_sc it feeds).

    Each named network must be in the donor and, where the base has it, of the same class; the
    base's other entries (its other networks, its acquisition settings) stay. The networks
    downstream of a replaced one were trained on the old one's outputs: fine-tune them after.
    Returns the new export, ready for ``torch.save``."""
    if not names:
        raise ValueError("replace_networks needs the names of the networks to take")
    out = read_network_file(base, "stage export")
    got = read_network_file(donor, "stage export")
    for path, ex in ((base, out), (donor, got)):
        if not isinstance(ex, dict) or _is_network_record(ex):
            raise NetworkFileError(f"{path}: not a stage export ({{name: network, ...}})")
    for name in names:
        rec = got.get(name)
        if not _is_network_record(rec):
            nets = sorted(n for n, r in got.items() if _is_network_record(r))
            raise NetworkFileError(f"{donor}: has no network {name!r}; its networks are {nets}")
        old = out.get(name)
        if old is not None and (not _is_network_record(old) or old["class"] != rec["class"]):
            raise NetworkFileError(f"{donor}: its {name!r} is a {rec['class']}, {base}'s is "
                                   f"{old['class'] if _is_network_record(old) else 'not a network'}")
        network_from_record(rec, f"{donor}: {name!r}")  # it must build
        out[name] = rec
    return out
