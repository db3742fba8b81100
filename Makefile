# Two commands do everything on a fresh machine: `make demo` (the main job) and `make test`.
PY := .venv/bin/python
PYTEST_ARGS ?=

.PHONY: setup demo test bench

setup:
	bash scripts/setup.sh

demo: setup
	$(PY) -m mitsvbrdf simulate scenes/lcd_rig.xml --material examples/materials/artificial_0.png \
		--patterns monograd --out out/demo

test: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

bench: setup
	for f in benchmarks/*.py; do $(PY) $$f || exit 1; done
