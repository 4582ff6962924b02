# The two commands a new user runs (see README): `make demo` and `make test`.
# Both create .venv on first use and install the package with its dev extras.

VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.stealth-ns-installed

.PHONY: env demo test test-fast test-gpu lint clean-env

env: $(STAMP)

$(STAMP): pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh "$(VENV)"
	@touch $(STAMP)

demo: env
	$(VENV)/bin/stealth-ns demo

test: env
	$(PY) -m pytest

test-fast: env
	$(PY) -m pytest -m "not slow"

# the CUDA path (gsplat against the compiled CPU backend, a poisoned run on the GPU); skipped without CUDA
test-gpu: env
	$(PY) -m pytest -m cuda

lint: env
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

clean-env:
	rm -rf $(VENV)
