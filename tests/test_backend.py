"""Backend selection: never hand Dr.Jit an old libLLVM, pick CUDA only when usable."""

import os
import subprocess
import sys

import pytest

from mitsvbrdf import backend as b
from mitsvbrdf.errors import BackendError

LDCONFIG = """\t3 libs found in cache `/etc/ld.so.cache'
\tlibLLVM-15.so.1 (libc6,x86-64) => /usr/lib/x86_64-linux-gnu/libLLVM-15.so.1
\tlibLLVM-14.so.1 (libc6,x86-64) => /usr/lib/x86_64-linux-gnu/libLLVM-14.so.1
\tlibLLVM.so.19.1 (libc6,x86-64) => /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
"""


@pytest.mark.parametrize("name,major", [("libLLVM-17.so.1", 17), ("libLLVM.so.19.1", 19), ("libLLVM-15.so", 15),
                                        ("/usr/lib/llvm-18/lib/libLLVM-18.so", 18), ("libLLVM.so", None),
                                        ("libLLVM.19.1.dylib", 19)])
def test_version_is_read_from_the_file_name(name, major):
    assert b.parse_llvm_major(name) == major


def test_newest_library_of_at_least_16_is_chosen():
    libs = [b.LibLLVM(p, b.parse_llvm_major(p)) for p in b.parse_ldconfig(LDCONFIG)]
    assert [lib.major for lib in libs] == [15, 14, 19]
    assert b.pick_newest(libs).path.endswith("libLLVM.so.19.1")


def test_only_old_libraries_give_none():
    libs = [b.LibLLVM("/x/libLLVM-15.so.1", 15), b.LibLLVM("/x/libLLVM-14.so.1", 14)]
    assert b.pick_newest(libs) is None


def test_env_var_to_a_missing_file_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-19.so"))
    with pytest.raises(BackendError, match="does not exist"):
        b.find_libllvm()


def test_env_var_to_an_old_library_is_a_clear_error(monkeypatch, tmp_path):
    old = tmp_path / "libLLVM-15.so.1"
    old.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(old))
    with pytest.raises(BackendError, match=">= 16"):
        b.find_libllvm()


def test_variant_choice_honours_argument_and_environment(monkeypatch):
    monkeypatch.delenv("MITSVBRDF_VARIANT", raising=False)
    assert b.choose_variant("scalar_rgb") == "scalar_rgb"
    monkeypatch.setenv("MITSVBRDF_VARIANT", "llvm_ad_rgb")
    assert b.choose_variant() == "llvm_ad_rgb"
    monkeypatch.delenv("MITSVBRDF_VARIANT")
    assert b.choose_variant() == ("cuda_ad_rgb" if b.cuda_available() else "llvm_ad_rgb")
    with pytest.raises(BackendError, match="unknown Mitsuba variant"):
        b.choose_variant("cuda_spectral_magic")


def _run(code, **env):
    e = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    e.update(env)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=e, timeout=300)


@pytest.mark.mitsuba
def test_llvm_variant_imports_and_computes_in_a_fresh_process():
    if b.find_libllvm() is None:
        pytest.skip("no libLLVM >= 16 on this machine")
    r = _run("import mitsvbrdf.backend as b; mi = b.import_mitsuba('llvm_ad_rgb'); import drjit as dr;"
             "print(dr.sum(dr.arange(mi.Float, 10))[0])")
    assert r.returncode == 0, r.stderr
    assert float(r.stdout) == 45.0


def test_old_libllvm_raises_instead_of_aborting():
    old = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1"
    if not os.path.exists(old):
        pytest.skip("no libLLVM-15 here to try")
    r = _run("import mitsvbrdf.backend as b\ntry:\n    b.import_mitsuba('llvm_ad_rgb')\n"
             "except b.BackendError as e:\n    print('refused:', e)", DRJIT_LIBLLVM_PATH=old)
    assert r.returncode == 0 and "refused" in r.stdout and ">= 16" in r.stdout
