# The two commands a new user runs (see README): `make demo` and `make test`.
# Both create .venv on first use and install the package with its dev extras.

VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.stealth-ns-installed

.PHONY: env demo test test-fast test-gpu lint docs clean-env

env: $(STAMP)

$(STAMP): pyproject.toml scripts/bootstrap.sh
	@bash scripts/bootstrap.sh "$(VENV)"
	@touch $(STAMP)

# DEMO_ARGS: extra options of stealth-ns demo (the docs' tests run it shortened: --iterations 60)
DEMO_ARGS ?=
demo: env
	$(VENV)/bin/stealth-ns demo $(DEMO_ARGS)

# Test processes side by side (pytest-xdist), each test file in one of them: most of the suite waits on
# one-threaded start-ups (torch, nerfstudio) of the commands it runs. On 2 cores: 1310 s with one, 643 s
# with two (docs/design/testing.md). TEST_WORKERS=0 runs the suite in this process (no xdist).
TEST_WORKERS ?= 2
PYTEST_ARGS := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile)

test: env
	$(PY) -m pytest $(PYTEST_ARGS)

test-fast: env
	$(PY) -m pytest $(PYTEST_ARGS) -m "not slow"

# the CUDA path (gsplat against the compiled CPU backend, a poisoned run on the GPU); skipped without CUDA
test-gpu: env
	$(PY) -m pytest -m cuda

# the docs site (docs/_build/html/index.html); warnings (a broken link, a missing page) are errors
docs: env
	$(VENV)/bin/sphinx-build -W --keep-going -q -b html docs docs/_build/html

lint: env
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

clean-env:
	rm -rf $(VENV)
