"""The wheel is a real package: it carries every module and what `mitsvbrdf demo` reads, and once
installed the demo runs outside the checkout.

The wheel is built from a copy of the checkout's package sources (nothing is written into the
checkout), with this interpreter's pip and setuptools, without build isolation or downloads. The
scratch environment sees this interpreter's site-packages through a ``.pth`` file (torch, Mitsuba,
Dr.Jit, pip; ``--system-site-packages`` would give the base interpreter's when this one is itself a
venv) and gets only the wheel, installed with ``--no-deps``. Directories a ``.pth`` file adds are not
site directories, so an editable install of the checkout there stays inactive.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from mitsvbrdf import backend

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow
if importlib.util.find_spec("pip") is None or importlib.util.find_spec("setuptools") is None:  # pragma: no cover
    pytest.skip("building the wheel needs pip and setuptools in this interpreter", allow_module_level=True)

#: Data files the demo and the default rig read (besides the modules).
DATA = ["mitsvbrdf/scenes/lcd_rig.xml", "mitsvbrdf/examples/artificial_0.png", "mitsvbrdf/examples/LICENSE-MIT",
        "mitsvbrdf/weights/networks.pt", "mitsvbrdf/render/ltc_table.npz"]


def _run(cmd: list, **kw) -> subprocess.CompletedProcess:
    res = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert res.returncode == 0, (f"{' '.join(map(str, cmd))}: exit {res.returncode}\n"
                                 f"{res.stdout[-3000:]}\n{res.stderr[-3000:]}")
    return res


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    skip = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for name in ("mitsvbrdf", "plugins"):
        shutil.copytree(ROOT / name, src / name, ignore=skip)
    dist = tmp_path_factory.mktemp("dist")
    _run([sys.executable, "-m", "pip", "wheel", src, "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", dist])
    (whl,) = dist.glob("mitsvbrdf-*.whl")
    return whl


def _checkout_modules() -> set[str]:
    """The wheel paths of the checkout's modules (plugins/ is installed as mitsvbrdf_plugins)."""
    out = {p.relative_to(ROOT).as_posix() for p in (ROOT / "mitsvbrdf").rglob("*.py")}
    out |= {"mitsvbrdf_plugins/" + p.relative_to(ROOT / "plugins").as_posix() for p in (ROOT / "plugins").rglob("*.py")}
    return out


def test_wheel_carries_every_module_the_scene_the_example_material_the_weights_and_the_ltc_table(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert not (_checkout_modules() - names), "modules missing from the wheel"
    assert not (set(DATA) - names), "data files missing from the wheel"


@pytest.mark.mitsuba
def test_installed_wheel_runs_the_demo_from_another_directory(wheel, tmp_path):
    if backend.find_libllvm() is None:  # pragma: no cover - depends on the machine
        pytest.skip("no libLLVM >= 16 for the LLVM backend")
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    purelib = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (purelib / "parent-site-packages.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    _run([python, "-m", "pip", "install", "--no-deps", "--no-index", "-q", wheel])
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["OMP_NUM_THREADS"] = "1"

    where = _run([python, "-c", "import mitsvbrdf, mitsvbrdf_plugins; print(mitsvbrdf.__file__); "
                  "print(mitsvbrdf_plugins.__file__)"], cwd=elsewhere, env=env).stdout.split()
    scratch = venv.resolve()
    assert all(Path(f).resolve().is_relative_to(scratch) for f in where), where

    _run([venv / "bin" / "mitsvbrdf", "demo", "--out", "out", "--resolution", "32", "--spp", "2", "--quiet"],
         cwd=elsewhere, env=env, timeout=600)
    rec = json.loads((elsewhere / "out" / "demo.json").read_text())
    assert Path(rec["material"]).resolve().is_relative_to(scratch)   # the packaged defaults were used
    assert Path(rec["networks"]).resolve().is_relative_to(scratch)
    assert rec["metrics"] and all(math.isfinite(v) for v in rec["metrics"].values())
    assert (elsewhere / "out" / "report.html").is_file()
