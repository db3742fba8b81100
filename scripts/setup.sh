#!/usr/bin/env bash
# Set up everything mitsvbrdf needs, idempotently: .venv with the pinned packages of
# requirements.lock, the package itself (editable), and a libLLVM >= 16 for Dr.Jit's LLVM backend
# (Debian's libllvm19 when none is present and we may install it).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

py=""
for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 10))'; then
        py="$cand"; break
    fi
done
[ -n "$py" ] || { echo "setup: need Python >= 3.10 (python3.11 preferred)" >&2; exit 1; }

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv with $($py --version)"
    "$py" -m venv .venv
fi

stamp=.venv/.mitsvbrdf-stamp
want="$(cat requirements.lock pyproject.toml | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    echo "setup: installing pinned packages (requirements.lock)"
    .venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
    .venv/bin/python -m pip install -q -r requirements.lock
    .venv/bin/python -m pip install -q --no-deps -e .
    echo "$want" > "$stamp"
else
    echo "setup: packages up to date"
fi

if ! llvm="$(.venv/bin/python -m mitsvbrdf.backend --check-llvm 2>/dev/null)"; then
    sudo=""
    [ "$(id -u)" = 0 ] || { command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null && sudo="sudo -n"; }
    if command -v apt-get >/dev/null 2>&1 && { [ "$(id -u)" = 0 ] || [ -n "$sudo" ]; }; then
        echo "setup: no libLLVM >= 16; installing Debian's libllvm19"
        $sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
        $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
    fi
    if ! llvm="$(.venv/bin/python -m mitsvbrdf.backend --check-llvm 2>/dev/null)"; then
        echo "setup: WARNING: no libLLVM >= 16 available; the torch renderers work, Mitsuba tests are skipped" >&2
        llvm=""
    fi
fi
[ -z "$llvm" ] || echo "setup: Dr.Jit LLVM backend uses $llvm"
