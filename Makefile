# Two commands do everything on a fresh machine: `make demo` (the main job) and `make test`.
# Every target first runs scripts/setup.sh (idempotent: .venv, pinned packages, libLLVM >= 16).
#   make test PYTEST_ARGS='-k backend -x'     extra pytest arguments
#   make test PYTEST_ARGS='-m "not mitsuba"'  skip the tests that need the Mitsuba backend
#   make test PYTEST_ARGS='-m "not slow"'     skip building and installing the wheel (tests/test_package.py)
PY := .venv/bin/python
PYTEST_ARGS ?=

.PHONY: setup demo test bench

setup:
	bash scripts/setup.sh

demo: setup
	$(PY) -m mitsvbrdf demo --out out/demo

test: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

bench: setup
	@set -e; for f in benchmarks/*.py; do \
		[ -e "$$f" ] || continue; \
		echo "+ $(PY) $$f"; $(PY) "$$f"; \
	done
