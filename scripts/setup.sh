#!/usr/bin/env bash
# Set up everything mitsvbrdf needs, idempotently, and say what is done:
#   1. .venv in the repository root (python3.11 if present, else python3 >= 3.10);
#   2. the pinned packages of requirements.lock, then the package itself (pip install --no-deps -e .),
#      skipped when .venv/.mitsvbrdf-stamp holds the sha256 of requirements.lock + pyproject.toml;
#   3. a libLLVM >= 16 for Dr.Jit's LLVM backend (`python -m mitsvbrdf.backend --check-llvm`);
#      if there is none and we are root (or have passwordless sudo) with apt-get, Debian's
#      libllvm19 is installed (libllvm18/17/16 where 19 is not packaged). Without one, the torch
#      renderers still work and the Mitsuba tests are skipped.
# Usage: bash scripts/setup.sh      (or `make setup`)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

say() { echo "setup: $*"; }
run() { echo "+ $*"; "$@"; }

# --- privileges for apt-get: root, or passwordless sudo -------------------------------------
sudo_cmd=()
can_apt=false
if command -v apt-get >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ]; then
        can_apt=true
    elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        sudo_cmd=(sudo -n)
        can_apt=true
    fi
fi
apt_updated=false
apt_install() {  # apt_install PKG...: non-interactive install (after one apt-get update)
    if [ "$apt_updated" = false ]; then
        run ${sudo_cmd[@]+"${sudo_cmd[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get update
        apt_updated=true
    fi
    run ${sudo_cmd[@]+"${sudo_cmd[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "$@"
}
apt_has() {  # apt_has PKG: the package has an install candidate
    local cand
    cand="$(apt-cache policy "$1" 2>/dev/null | awk '/Candidate:/ {print $2}')"
    [ -n "$cand" ] && [ "$cand" != "(none)" ]
}

# --- 1. Python and the virtual environment --------------------------------------------------
py=""
for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 &&
        "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
        py="$(command -v "$cand")"
        break
    fi
done
if [ -z "$py" ]; then
    echo "setup: ERROR: need Python >= 3.10 (python3.11 preferred); found none on PATH" >&2
    exit 1
fi

venv_ok() { [ -x .venv/bin/python ] && .venv/bin/python -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; }
if [ -e .venv ] && ! venv_ok; then
    echo "setup: ERROR: .venv exists but its Python is missing or older than 3.10; remove it (rm -rf .venv) and run again" >&2
    exit 1
fi
if [ ! -e .venv ]; then
    say "creating .venv with $("$py" --version 2>&1) ($py)"
    if ! run "$py" -m venv .venv; then
        rm -rf .venv
        ver="$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
        if [ "$can_apt" = true ]; then
            say "the venv module is incomplete; installing Debian's python$ver-venv"
            if apt_has "python$ver-venv"; then apt_install "python$ver-venv"; else apt_install python3-venv; fi
            run "$py" -m venv .venv
        else
            echo "setup: ERROR: '$py -m venv' failed; install python$ver-venv (Debian/Ubuntu) and run again" >&2
            exit 1
        fi
    fi
else
    say ".venv exists ($(.venv/bin/python --version 2>&1))"
fi
if ! .venv/bin/python -m pip --version >/dev/null 2>&1; then
    say ".venv has no pip; adding it"
    run .venv/bin/python -m ensurepip --upgrade
fi

# --- 2. Pinned packages and the package itself ----------------------------------------------
stamp=.venv/.mitsvbrdf-stamp
want="$(cat requirements.lock pyproject.toml | sha256sum | cut -d' ' -f1)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    say "packages up to date (requirements.lock and pyproject.toml unchanged since the last install)"
else
    say "installing the pinned packages of requirements.lock, then mitsvbrdf itself (editable)"
    rm -f "$stamp"
    run .venv/bin/python -m pip install --disable-pip-version-check -r requirements.lock
    run .venv/bin/python -m pip install --disable-pip-version-check --no-deps -e .
    echo "$want" > "$stamp"
    say "wrote $stamp"
fi

# --- 3. libLLVM >= 16 for Dr.Jit's LLVM backend ---------------------------------------------
check_llvm() { .venv/bin/python -m mitsvbrdf.backend --check-llvm; }
say "looking for a libLLVM >= 16 for Dr.Jit (python -m mitsvbrdf.backend --check-llvm)"
llvm="$(check_llvm)" || llvm=""
if [ -z "$llvm" ] && [ -n "${DRJIT_LIBLLVM_PATH:-}" ]; then
    # An explicit choice is never overridden (the message above says what is wrong with it).
    echo "setup: WARNING: DRJIT_LIBLLVM_PATH=$DRJIT_LIBLLVM_PATH is not usable; Mitsuba's LLVM" \
         "variants refuse to start until you unset it or point it at a libLLVM >= 16." >&2
elif [ -z "$llvm" ]; then
    if [ "$can_apt" = true ]; then
        say "no libLLVM >= 16; installing one with apt-get"
        run ${sudo_cmd[@]+"${sudo_cmd[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get update
        apt_updated=true
        pkg=""
        for cand in libllvm19 libllvm18 libllvm17 libllvm16; do
            if apt_has "$cand"; then pkg="$cand"; break; fi
        done
        if [ -n "$pkg" ]; then
            apt_install "$pkg" || say "installing $pkg failed"
            llvm="$(check_llvm)" || llvm=""
        else
            say "apt offers none of libllvm19/18/17/16"
        fi
    else
        say "cannot install libllvm19 here (needs apt-get and root or passwordless sudo)"
    fi
    if [ -z "$llvm" ]; then
        echo "setup: WARNING: no libLLVM >= 16 available: the torch renderers work, but Mitsuba" \
             "rendering on the CPU does not and the Mitsuba tests will be skipped. Fix: install" \
             "Debian's libllvm19 (apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH to a libLLVM >= 16." >&2
    fi
fi
[ -z "$llvm" ] || say "Dr.Jit's LLVM backend will use $llvm"
say "done"
