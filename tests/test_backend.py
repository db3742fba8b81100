"""Backend selection: never hand Dr.Jit an old libLLVM, pick CUDA only when usable.

Parsing and selection are tested on fake file names and fake ``ldconfig -p`` text. Everything that
loads a real libLLVM or imports drjit runs in a subprocess, so a library that aborts the process
(LLVM 15 does, inside Dr.Jit kernels) can never take pytest down with it.
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

LIBDIR = "/usr/lib/x86_64-linux-gnu"
OLD_LLVM = f"{LIBDIR}/libLLVM-15.so.1"

LDCONFIG = """\t7 libs found in cache `/etc/ld.so.cache'
\tlibLLVMSPIRVLib.so.15 (libc6,x86-64) => /lib/x86_64-linux-gnu/libLLVMSPIRVLib.so.15
\tlibLLVM.so.19.1 (libc6,x86-64) => /lib/x86_64-linux-gnu/libLLVM.so.19.1
\tlibLLVM-15.so.1 (libc6,x86-64) => /lib/x86_64-linux-gnu/libLLVM-15.so.1
\tlibLLVM-15.so (libc6,x86-64) => /lib/x86_64-linux-gnu/libLLVM-15.so
\tlibLLVM-14.so.1 (libc6,x86-64) => /lib/x86_64-linux-gnu/libLLVM-14.so.1
\tlibLLVM-18.so.1 (libc6) => /lib/i386-linux-gnu/libLLVM-18.so.1
\tlibc.so.6 (libc6,x86-64) => /lib/x86_64-linux-gnu/libc.so.6
"""


# --------------------------------------------------------------------------- pure parsing


@pytest.mark.parametrize("name,major", [
    ("libLLVM-17.so.1", 17), ("libLLVM.so.19.1", 19), ("libLLVM-15.so", 15),
    ("/usr/lib/llvm-18/lib/libLLVM-18.so", 18), ("libLLVM-14.0.6.so.1", 14), ("libLLVM-19.dylib", 19),
    ("libLLVM.so", None), ("libLLVM.dylib", None), ("libLLVMSupport.a", None), ("libc.so.6", None),
])
def test_version_is_read_from_the_file_name(name, major):
    assert b.parse_llvm_major(name) == major


@pytest.mark.parametrize("name,ok", [
    ("libLLVM-19.so", True), ("libLLVM.so.19.1", True), ("libLLVM.so", True), ("libLLVM.dylib", True),
    ("libLLVM-14.0.6.so.1", True), ("libLLVMSPIRVLib.so.15", False), ("libLLVM-C.so", False),
    ("libLLVMSupport.a", False), ("LLVMgold.so", False),
])
def test_only_whole_libllvm_libraries_are_candidates(name, ok):
    assert b.is_libllvm_name(name) is ok


def test_ldconfig_text_is_parsed_in_order_skipping_components_and_other_architectures():
    assert b.parse_ldconfig(LDCONFIG, "x86_64") == [
        "/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/lib/x86_64-linux-gnu/libLLVM-15.so.1",
        "/lib/x86_64-linux-gnu/libLLVM-15.so", "/lib/x86_64-linux-gnu/libLLVM-14.so.1"]
    assert "/lib/i386-linux-gnu/libLLVM-18.so.1" in b.parse_ldconfig(LDCONFIG, None)
    assert b.parse_ldconfig("", "x86_64") == []


def test_newest_library_of_at_least_16_is_chosen():
    libs = [b.LibLLVM(p, b.parse_llvm_major(p)) for p in b.parse_ldconfig(LDCONFIG, "x86_64")]
    assert sorted(lib.major for lib in libs) == [14, 15, 15, 19]
    assert b.pick_newest(libs) == b.LibLLVM("/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19)
    assert b.pick_newest(libs, min_major=20) is None


def test_only_old_libraries_give_none():
    only_old = LDCONFIG.replace("libLLVM.so.19.1", "libLLVM-14.0.6.so.1")
    libs = [b.LibLLVM(p, b.parse_llvm_major(p)) for p in b.parse_ldconfig(only_old, "x86_64")]
    assert libs and b.pick_newest(libs) is None


# --------------------------------------------------------------------------- discovery on fake files


@pytest.fixture
def fake_system(monkeypatch, tmp_path):
    """A fake library folder: ldconfig lists what `ldconfig` names; SEARCH_DIRS is `tmp/search`."""
    monkeypatch.delenv(b.ENV_LLVM, raising=False)
    libdir, search = tmp_path / "lib", tmp_path / "search"
    libdir.mkdir()
    search.mkdir()
    monkeypatch.setattr(b, "SEARCH_DIRS", (str(search),))
    monkeypatch.setattr(b.platform, "machine", lambda: "x86_64")

    def install(ldconfig: list[str] = (), searched: list[str] = ()) -> None:
        lines = []
        for name in ldconfig:
            (libdir / name).write_bytes(b"")  # never loaded: versions come from the names
            lines.append(f"\t{name} (libc6,x86-64) => {libdir / name}")
        for name in searched:
            (search / name).write_bytes(b"")
        monkeypatch.setattr(b, "_ldconfig_output", lambda: "\n".join(lines))

    return install


def test_find_picks_19_among_14_15_19(fake_system):
    fake_system(ldconfig=["libLLVM-14.so.1", "libLLVM-15.so.1", "libLLVM.so.19.1"])
    lib = b.find_libllvm()
    assert lib is not None and lib.major == 19 and lib.path.endswith("libLLVM.so.19.1")
    assert lib.source == "ldconfig"


def test_find_gives_none_with_only_14_and_15(fake_system):
    # The unversioned libLLVM.so is asked for its version in a subprocess; it cannot be loaded.
    fake_system(ldconfig=["libLLVM-14.so.1", "libLLVM-15.so.1"], searched=["libLLVM.so"])
    assert b.find_libllvm() is None


def test_find_searches_folders_and_follows_unversioned_links(fake_system, tmp_path):
    fake_system(ldconfig=["libLLVM-15.so.1"], searched=["libLLVM-17.so.1"])
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / "libLLVM-21.so.1").write_bytes(b"")
    (tmp_path / "search" / "libLLVM.so").symlink_to(other / "libLLVM-21.so.1")
    lib = b.find_libllvm()
    assert lib is not None and lib.major == 21 and lib.source == "search"


def test_a_library_that_cannot_be_loaded_is_reported_not_crashing(tmp_path):
    junk = tmp_path / "libLLVM.so"
    junk.write_bytes(b"not an ELF file")
    major, detail = b.probe_library(str(junk))
    assert major is None and "cannot be loaded" in detail


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


def test_env_var_wins_over_newer_libraries(monkeypatch, tmp_path, fake_system):
    fake_system(ldconfig=["libLLVM-20.so.1"])
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
    monkeypatch.setattr(b, "find_libllvm", lambda min_major=b.MIN_LLVM: lib)
    assert b.configure_llvm() == lib
    assert os.environ[b.ENV_LLVM] == lib.path


def test_configure_without_a_library_says_how_to_fix_it(monkeypatch, no_drjit):
    monkeypatch.setattr(b, "find_libllvm", lambda min_major=b.MIN_LLVM: None)
    with pytest.raises(BackendError, match=r"no libLLVM >= 16 .*apt-get install libllvm19"):
        b.configure_llvm()
    assert b.ENV_LLVM not in os.environ


def _fake_drjit(monkeypatch, version):
    fake = types.SimpleNamespace(detail=types.SimpleNamespace(llvm_version=lambda: version))
    monkeypatch.setitem(sys.modules, "drjit", fake)


def test_configure_after_drjit_loaded_an_old_library_refuses(monkeypatch):
    _fake_drjit(monkeypatch, (15, 0, 6))
    with pytest.raises(BackendError, match="before importing drjit/mitsuba"):
        b.configure_llvm()


def test_configure_after_drjit_loaded_a_good_library_accepts_it(monkeypatch):
    _fake_drjit(monkeypatch, (19, 1, 7))
    lib = b.configure_llvm()
    assert lib.major == 19 and lib.source == "drjit"


# --------------------------------------------------------------------------- variants


def test_variant_choice_honours_argument_and_environment(monkeypatch):
    monkeypatch.delenv(b.ENV_VARIANT, raising=False)
    assert b.choose_variant("scalar_rgb") == "scalar_rgb"
    monkeypatch.setenv(b.ENV_VARIANT, "cuda_rgb")
    assert b.choose_variant() == "cuda_rgb"
    assert b.choose_variant("llvm_rgb") == "llvm_rgb"  # the argument beats the environment
    monkeypatch.delenv(b.ENV_VARIANT)
    assert b.choose_variant() == ("cuda_ad_rgb" if b.cuda_available() else "llvm_ad_rgb")
    monkeypatch.setattr(b, "cuda_available", lambda: True)
    assert b.choose_variant() == "cuda_ad_rgb"
    monkeypatch.setattr(b, "cuda_available", lambda: False)
    assert b.choose_variant() == "llvm_ad_rgb"


def test_unknown_variants_are_rejected(monkeypatch):
    with pytest.raises(BackendError, match="unknown Mitsuba variant 'cuda_spectral_magic'"):
        b.choose_variant("cuda_spectral_magic")
    monkeypatch.setenv(b.ENV_VARIANT, "llvm")
    with pytest.raises(BackendError, match="MITSVBRDF_VARIANT"):
        b.choose_variant()


def test_torch_device_follows_the_variant():
    assert b.torch_device_for("cuda_ad_rgb").type == "cuda"
    assert b.torch_device_for("llvm_ad_rgb").type == "cpu"
    assert b.torch_device_for("scalar_rgb").type == "cpu"


def test_cuda_available_never_raises():
    assert isinstance(b.cuda_available(), bool)


# --------------------------------------------------------------------------- subprocesses


def _run(args: list[str], **env: str) -> subprocess.CompletedProcess:
    e = {k: v for k, v in os.environ.items() if k not in (b.ENV_LLVM, b.ENV_VARIANT)}
    e.update(env)
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=e, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])


def test_command_line_report_and_check(monkeypatch):
    monkeypatch.delenv(b.ENV_LLVM, raising=False)  # as in the subprocesses
    r = _run(["-m", "mitsvbrdf.backend"])
    assert r.returncode == 0, r.stderr
    assert "variant:" in r.stdout and "libLLVM:" in r.stdout and "CUDA:" in r.stdout
    r = _run(["-m", "mitsvbrdf.backend", "--check-llvm"])
    lib = b.find_libllvm()
    assert r.returncode == (1 if lib is None else 0)
    assert r.stdout.strip() == (lib.path if lib else "")
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
