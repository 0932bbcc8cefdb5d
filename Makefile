# Two commands do all the set-up on a fresh machine:
#   make demo   - the main job on bundled data (the milling arm), results in demo-output/
#   make test   - installs what the tests need, then runs them
#   make docs   - builds the documentation site into docs/_build/html (warnings are errors)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: demo test install browser bench docs clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/chainspace demo --out demo-output --overwrite

# Headless Chromium for the browser test; where it cannot be installed that test skips and says why.
browser:
	@command -v chromium >/dev/null 2>&1 || \
	  { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] && \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null) ; } || \
	  echo "note: chromium could not be installed; the browser test will be skipped"

# one worker per core, idle workers take queued tests; one BLAS thread per worker: the fits' many small
# solves run several times slower when each worker's BLAS threads compete for the same cores
test: install browser
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist worksteal

# Every suite in benchmarks/ with its --quick settings; exit code 77 from a script means its data are
# missing (it says which); set CHAINSPACE_DATA to the shared data folder for the CMU/DeepMimic/dog rows.
bench: install
	@failed=""; skipped=""; \
	for f in benchmarks/bench_*.py; do \
	  echo "== $$f --quick"; \
	  $(BIN)/python $$f --quick; rc=$$?; \
	  if [ $$rc = 77 ]; then skipped="$$skipped $$f"; elif [ $$rc != 0 ]; then failed="$$failed $$f"; fi; \
	done; \
	[ -z "$$skipped" ] || echo "skipped (data missing):$$skipped"; \
	if [ -n "$$failed" ]; then echo "failed or missed a target:$$failed"; exit 1; fi

docs: install
	$(BIN)/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "docs: open docs/_build/html/index.html"

clean:
	rm -rf $(VENV) build dist *.egg-info demo-output bench-output docs/_build
