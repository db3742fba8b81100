"""Backend selection: never hand Dr.Jit an old libLLVM, pick CUDA only when usable.

Discovery is tested on empty files in fake folders (versions come from their names). Everything
that loads a real libLLVM or imports drjit runs in a subprocess, so a library that aborts the
process (LLVM 15 does, inside Dr.Jit kernels) can never take pytest down with it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

from mitsvbrdf import backend as b
from mitsvbrdf.errors import BackendError

OLD_LLVM = f"/usr/lib/{os.uname().machine}-linux-gnu/libLLVM-15.so.1"


# --------------------------------------------------------------------------- file names


@pytest.mark.parametrize("name,major", [
    ("libLLVM-17.so.1", 17), ("libLLVM.so.19.1", 19), ("libLLVM-15.so", 15),
    ("/usr/lib/llvm-18/lib/libLLVM-18.so", 18), ("libLLVM-14.0.6.so.1", 14),
    ("libLLVM.so", None), ("libLLVMSPIRVLib.so.15", None), ("libLLVM-C.so", None),
    ("libLLVMSupport.a", None), ("libc.so.6", None),
])
def test_version_is_read_from_the_file_name(name, major):
    assert b.parse_llvm_major(name) == major


# --------------------------------------------------------------------------- discovery on fake files


@pytest.fixture
def folders(monkeypatch, tmp_path):
    """Two fake library folders searched in order; returns a function that creates empty files."""
    monkeypatch.delenv(b.ENV_LLVM, raising=False)
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    monkeypatch.setattr(b, "SEARCH_DIRS", (str(first), str(second)))

    def install(*names: str, folder: Path = first) -> None:
        for name in names:
            (folder / name).write_bytes(b"")  # never loaded: versions come from the names

    install.first, install.second = first, second
    return install


def test_find_picks_the_newest_of_at_least_16(folders):
    folders("libLLVM-14.so.1", "libLLVM-17.so.1")
    folders("libLLVM-15.so.1", "libLLVM.so.19.1", folder=folders.second)
    assert b.find_libllvm() == b.LibLLVM(str(folders.second / "libLLVM.so.19.1"), 19)


def test_find_gives_none_with_only_old_or_unloadable_libraries(folders):
    folders("libLLVM-14.so.1", "libLLVM-15.so.1", "libLLVM.so")  # libLLVM.so: asked, cannot load
    assert b.find_libllvm() is None


def test_find_follows_an_unversioned_link_to_its_versioned_name(folders, tmp_path):
    (tmp_path / "libLLVM-21.so.1").write_bytes(b"")
    (folders.first / "libLLVM.so").symlink_to(tmp_path / "libLLVM-21.so.1")
    assert b.find_libllvm() == b.LibLLVM(str(folders.first / "libLLVM.so"), 21)


def test_find_expands_wildcards_in_folders(monkeypatch, tmp_path):
    monkeypatch.delenv(b.ENV_LLVM, raising=False)
    (tmp_path / "llvm-18" / "lib").mkdir(parents=True)
    (tmp_path / "llvm-18" / "lib" / "libLLVM-18.so").write_bytes(b"")
    monkeypatch.setattr(b, "SEARCH_DIRS", (str(tmp_path / "llvm-*" / "lib"),))
    assert b.find_libllvm().major == 18


def test_find_never_loads_llvm_component_libraries(folders, monkeypatch):
    probed = []
    monkeypatch.setattr(b, "_probe", lambda path: probed.append(os.path.basename(path)) or (None, "fake"))
    folders("libLLVMSPIRVLib.so.15", "libLLVM-C.so", "libLLVM.so")
    b.find_libllvm()
    assert probed == ["libLLVM.so"]


def test_a_library_that_cannot_be_loaded_is_reported_not_crashing(tmp_path):
    junk = tmp_path / "libLLVM.so"
    junk.write_bytes(b"not an ELF file")
    major, why = b.library_version(str(junk))
    assert major is None and "cannot be loaded" in why


# --------------------------------------------------------------------------- DRJIT_LIBLLVM_PATH


def test_env_var_to_a_missing_file_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv(b.ENV_LLVM, str(tmp_path / "libLLVM-19.so"))
    with pytest.raises(BackendError, match="not an existing file") as e:
        b.find_libllvm()
    assert "apt-get install libllvm19" in str(e.value)


def test_env_var_to_an_old_library_is_a_clear_error(monkeypatch, tmp_path):
    old = tmp_path / "libLLVM-15.so.1"
    old.write_bytes(b"")
    monkeypatch.setenv(b.ENV_LLVM, str(old))
    with pytest.raises(BackendError, match=r"is libLLVM 15, but .* needs libLLVM >= 16"):
        b.find_libllvm()


def test_env_var_to_an_unloadable_unversioned_file_is_a_clear_error(monkeypatch, tmp_path):
    junk = tmp_path / "libLLVM.so"
    junk.write_bytes(b"garbage")
    monkeypatch.setenv(b.ENV_LLVM, str(junk))
    with pytest.raises(BackendError, match="cannot be loaded"):
        b.find_libllvm()


def test_env_var_wins_over_newer_libraries(monkeypatch, tmp_path, folders):
    folders("libLLVM-20.so.1")
    mine = tmp_path / "libLLVM-17.so"
    mine.write_bytes(b"")
    monkeypatch.setenv(b.ENV_LLVM, str(mine))
    assert b.find_libllvm() == b.LibLLVM(str(mine), 17)


# --------------------------------------------------------------------------- configure_llvm


@pytest.fixture
def no_drjit(monkeypatch):
    """Pretend drjit is not imported yet, and restore DRJIT_LIBLLVM_PATH afterwards."""
    monkeypatch.delitem(sys.modules, "drjit", raising=False)
    monkeypatch.setenv(b.ENV_LLVM, "placeholder")  # so that monkeypatch restores the real state
    monkeypatch.delenv(b.ENV_LLVM)


def test_configure_sets_the_env_var(monkeypatch, no_drjit):
    lib = b.LibLLVM("/opt/llvm/libLLVM-19.so", 19)
    monkeypatch.setattr(b, "find_libllvm", lambda: lib)
    assert b.configure_llvm() == lib
    assert os.environ[b.ENV_LLVM] == lib.path


def test_configure_without_a_library_says_how_to_fix_it(monkeypatch, no_drjit):
    monkeypatch.setattr(b, "find_libllvm", lambda: None)
    with pytest.raises(BackendError, match=r"no libLLVM >= 16 .*apt-get install libllvm19"):
        b.configure_llvm()
    assert b.ENV_LLVM not in os.environ


def _fake_drjit(monkeypatch, version):
    fake = types.SimpleNamespace(detail=types.SimpleNamespace(llvm_version=lambda: version))
    monkeypatch.setitem(sys.modules, "drjit", fake)


def test_configure_after_drjit_loaded_an_old_library_refuses(monkeypatch):
    _fake_drjit(monkeypatch, (15, 0, 6))
    with pytest.raises(BackendError, match="loaded libLLVM 15.*before importing drjit/mitsuba"):
        b.configure_llvm()


def test_configure_after_drjit_loaded_a_good_library_accepts_it(monkeypatch):
    _fake_drjit(monkeypatch, (19, 1, 7))
    assert b.configure_llvm().major == 19


# --------------------------------------------------------------------------- variants


@pytest.fixture
def no_variant_env(monkeypatch):
    monkeypatch.delenv(b.ENV_VARIANT, raising=False)


def test_variant_argument_is_used(no_variant_env):
    assert b.choose_variant("cuda_ad_rgb") == "cuda_ad_rgb"


def test_variant_environment_is_used_without_an_argument(monkeypatch):
    monkeypatch.setenv(b.ENV_VARIANT, "cuda_ad_rgb")
    assert b.choose_variant() == "cuda_ad_rgb"


def test_variant_argument_beats_the_environment(monkeypatch):
    monkeypatch.setenv(b.ENV_VARIANT, "cuda_ad_rgb")
    assert b.choose_variant("llvm_ad_rgb") == "llvm_ad_rgb"


@pytest.mark.parametrize("cuda,variant", [(True, "cuda_ad_rgb"), (False, "llvm_ad_rgb")])
def test_variant_default_follows_cuda(monkeypatch, no_variant_env, cuda, variant):
    monkeypatch.setattr(b.torch.cuda, "is_available", lambda: cuda)
    assert b.choose_variant() == variant


def test_variants_other_than_the_two_differentiable_ones_are_rejected(monkeypatch, no_variant_env):
    with pytest.raises(BackendError, match="unknown Mitsuba variant 'scalar_rgb'"):
        b.choose_variant("scalar_rgb")
    monkeypatch.setenv(b.ENV_VARIANT, "llvm")
    with pytest.raises(BackendError, match="MITSVBRDF_VARIANT"):
        b.choose_variant()


# --------------------------------------------------------------------------- subprocesses


def _run(args: list[str], **env: str) -> subprocess.CompletedProcess:
    e = {k: v for k, v in os.environ.items() if k not in (b.ENV_LLVM, b.ENV_VARIANT)}
    e.update(env)
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=e, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])


def test_check_llvm_prints_the_library_found(monkeypatch):
    monkeypatch.delenv(b.ENV_LLVM, raising=False)  # as in the subprocess
    r = _run(["-m", "mitsvbrdf.backend", "--check-llvm"])
    lib = b.find_libllvm()
    assert r.returncode == (1 if lib is None else 0)
    assert r.stdout.strip() == (lib.path if lib else "")


def test_check_llvm_fails_on_a_bad_env_var():
    r = _run(["-m", "mitsvbrdf.backend", "--check-llvm"], DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so")
    assert r.returncode == 1 and "not an existing file" in r.stderr


@pytest.mark.mitsuba
def test_llvm_variant_imports_and_computes_in_a_fresh_process(monkeypatch):
    monkeypatch.delenv(b.ENV_LLVM, raising=False)  # as in the subprocess
    if b.find_libllvm() is None:
        pytest.skip(f"no libLLVM >= 16 on this machine; {b.FIX}")
    # dr.minimum on floats is the operation that aborts the process under LLVM 15.
    code = ("import sys; import mitsvbrdf.backend as b; assert 'drjit' not in sys.modules\n"
            "mi = b.import_mitsuba('llvm_ad_rgb'); import drjit as dr\n"
            "x = dr.minimum(dr.arange(mi.Float, 10), 4.0)\n"
            "print(mi.variant(), dr.sum(x)[0], dr.detail.llvm_version()[0])")
    r = _run(["-c", code])
    assert r.returncode == 0, r.stderr
    variant, total, major = r.stdout.split()
    assert variant == "llvm_ad_rgb" and float(total) == 30.0 and int(major) >= 16


def test_old_libllvm_in_env_raises_instead_of_aborting():
    if not os.path.exists(OLD_LLVM):
        pytest.skip(f"no {OLD_LLVM} here to try")
    code = ("import sys; import mitsvbrdf.backend as b\n"
            "for f in (b.configure_llvm, lambda: b.import_mitsuba('llvm_ad_rgb')):\n"
            "    try:\n        f()\n    except b.BackendError as e:\n        print('refused:', e)\n"
            "print('drjit imported:', 'drjit' in sys.modules)")
    r = _run(["-c", code], DRJIT_LIBLLVM_PATH=OLD_LLVM)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("refused:") == 2 and "is libLLVM 15" in r.stdout and ">= 16" in r.stdout
    assert "drjit imported: False" in r.stdout


@pytest.mark.mitsuba
def test_drjit_imported_with_old_libllvm_is_refused_instead_of_aborting():
    if not os.path.exists(OLD_LLVM):
        pytest.skip(f"no {OLD_LLVM} here to try")
    code = ("import os, drjit\n"  # drjit loads libLLVM 15 here, at import
            "del os.environ['DRJIT_LIBLLVM_PATH']\n"
            "import mitsvbrdf.backend as b\n"
            "try:\n    b.import_mitsuba('llvm_ad_rgb')\nexcept b.BackendError as e:\n    print('refused:', e)")
    r = _run(["-c", code], DRJIT_LIBLLVM_PATH=OLD_LLVM)
    assert r.returncode == 0, r.stderr
    assert "refused:" in r.stdout and "loaded libLLVM 15" in r.stdout
