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


def save_network(path: str | Path, net: nn.Module) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(network_record(net), tmp)
    tmp.replace(path)


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
