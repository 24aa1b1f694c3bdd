# Two commands for a fresh machine (each sets everything up first):
#   make demo   reconstruct the bundled sample scan and print the quality summary
#   make test   run the test-suite
PY := .venv/bin/python
OPRECON := .venv/bin/oprecon
LINTED := recon cli configs tests benchmarks scripts

.PHONY: setup demo test test-compile test-compile-fit test-compile-remesh test-nojit test-checks test-suite test-wheel lint format bench refresh-references clean

setup:
	@bash scripts/setup.sh

demo: setup
	@mkdir -p demo_output
	$(OPRECON) info sample_data/bunny-sparse.ply
	$(OPRECON) fit sample_data/bunny-sparse.ply -o demo_output/bunny-sparse.ply \
		--particles demo_output/bunny-sparse-particles.ply --preview demo_output/bunny-sparse.png
	@echo "demo: wrote demo_output/bunny-sparse.ply, its .report.json and a preview PNG"

# make test: lint, then on two make jobs (-j2) everything the suite needs, and the suite.
# - test-compile: a fit of the bundled sample and a remesh of the bundled L-block compile the
#   kernels into numba's cache, one command per core; otherwise every test worker compiles its
#   own copy of the same kernels at once. Between them they call every kernel of a fit; the
#   remesh compiles the step kernel and the mesh kernels while the fit compiles the normals'
#   and the seeds' kernels, then loads the step kernel from the cache (on a fresh clone of the
#   2-core AVX2 machine, 2026-11-30: the fit alone compiles for 3m26s, the remesh for 1m28s
#   and the fit after it for 1m58s; a few seconds each once cached).
# - test-nojit: the kernel tests once more in pure Python (numba's JIT off), so coverage and
#   tracebacks see the kernels' source. It starts when a compile command ends.
# - test-wheel: scripts/check_wheel.sh installs the wheel in a scratch venv and fits a sample
#   with it, JIT off (a JIT fit there would compile every kernel once more: the cache belongs
#   to the source files' paths).
# - test-suite, once the compile and the JIT-off pass are done: the docstring examples, then
#   the suite.
# The JIT-off pass and the suite run on TEST_WORKERS processes (pytest-xdist, one test file per
# worker at a time, so a file's module fixtures are built once; `logical`: one per logical CPU,
# at most 4); TEST_WORKERS=0 runs them in one process.
TEST_WORKERS ?= logical
XDIST := -n $(TEST_WORKERS) --maxprocesses=4 --dist loadfile

test: setup
	$(PY) -m ruff check $(LINTED)
	$(PY) -m ruff format --check $(LINTED)
	@$(MAKE) --no-print-directory -j2 test-suite test-wheel

test-compile: test-compile-fit test-compile-remesh

test-compile-fit: setup
	@out=$$(mktemp -d) && trap 'rm -rf "$$out"' EXIT && \
	  echo "test-compile: fitting sample_data/bunny-sparse.ply (compiles the fit kernels once)" && \
	  $(OPRECON) fit sample_data/bunny-sparse.ply -o "$$out/bunny-sparse.ply" -q

test-compile-remesh: setup
	@out=$$(mktemp -d) && trap 'rm -rf "$$out"' EXIT && \
	  echo "test-compile: remeshing sample_data/lblock-gt.ply (compiles the step and mesh kernels once)" && \
	  $(OPRECON) remesh sample_data/lblock-gt.ply -o "$$out/lblock.ply" -q

test-nojit: setup
	NUMBA_DISABLE_JIT=1 $(PY) -m pytest -q -p no:cacheprovider $(XDIST) tests/kernels

test-checks: test-compile test-nojit
	$(PY) -m pytest -q -p no:cacheprovider --doctest-modules recon

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
