# Two commands for a fresh machine (each sets everything up first):
#   make demo   reconstruct the bundled sample scan and print the quality summary
#   make test   run the test-suite
PY := .venv/bin/python
OPRECON := .venv/bin/oprecon
LINTED := recon cli configs tests benchmarks scripts

.PHONY: setup demo test test-compile test-checks test-suite test-wheel lint format bench refresh-references clean

setup:
	@bash scripts/setup.sh

demo: setup
	@mkdir -p demo_output
	$(OPRECON) info sample_data/bunny-sparse.ply
	$(OPRECON) fit sample_data/bunny-sparse.ply -o demo_output/bunny-sparse.ply \
		--particles demo_output/bunny-sparse-particles.ply --preview demo_output/bunny-sparse.png
	@echo "demo: wrote demo_output/bunny-sparse.ply, its .report.json and a preview PNG"

# make test: lint, then the docstring examples, a pure-Python pass of the kernel tests (numba's
# JIT off, so coverage and tracebacks see the kernels' source) and the suite; beside those, the
# installed wheel. The wheel's fit compiles every fit kernel once more in its scratch venv
# (3m37s of one core on the 2-core AVX2 machine, 2026-11-30), so it runs as a second job from
# the start. On the other core one fit of the bundled sample compiles the fit kernels into
# numba's cache first (test-compile: 3m30s on a fresh clone there, a few seconds once cached):
# otherwise every test worker compiles its own copy of the same kernels at once. The JIT-off
# pass and the suite run on TEST_WORKERS processes (pytest-xdist, one test file per worker at a
# time, so a file's module fixtures are built once; `logical`: one per logical CPU, at most 4);
# TEST_WORKERS=0 runs them in one process.
TEST_WORKERS ?= logical
XDIST := -n $(TEST_WORKERS) --maxprocesses=4 --dist loadfile

test: setup
	$(PY) -m ruff check $(LINTED)
	$(PY) -m ruff format --check $(LINTED)
	@$(MAKE) --no-print-directory -j2 test-wheel test-suite

test-compile: setup
	@out=$$(mktemp -d) && trap 'rm -rf "$$out"' EXIT && \
	  echo "test-compile: fitting sample_data/bunny-sparse.ply (compiles the fit kernels once)" && \
	  $(OPRECON) fit sample_data/bunny-sparse.ply -o "$$out/bunny-sparse.ply" -q

test-checks: test-compile
	$(PY) -m pytest -q -p no:cacheprovider --doctest-modules recon
	NUMBA_DISABLE_JIT=1 $(PY) -m pytest -q -p no:cacheprovider $(XDIST) tests/kernels

test-suite: test-checks
	$(PY) -m pytest -q $(XDIST)

test-wheel: setup
	bash scripts/check_wheel.sh

lint: setup
	$(PY) -m ruff check $(LINTED)
	$(PY) -m ruff format --check $(LINTED)

format: setup
	$(PY) -m ruff format $(LINTED)
	$(PY) -m ruff check --fix $(LINTED)

# Refit the regression samples, print each metric change (vs the old reference and the ground
# truth), re-measure the float noise and write sample_data/references/. Only look, write
# nothing: make refresh-references ARGS=--check   (some entries: ARGS="bunny-sparse")
refresh-references: setup
	$(PY) scripts/refresh_references.py $(ARGS)

clean:
	rm -rf demo_output bench_output .pytest_cache
	find recon -name '*.nbi' -delete -o -name '*.nbc' -delete  # numba's compile cache
