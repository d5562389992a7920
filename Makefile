# Two commands do all set-up on a fresh machine with Python ≥ 3.10:
#   make fit    # venv + install + train the default config (CONFIG=spring_fast.yaml)
#   make test   # venv + install + the test suite's default tier (3½–5 min on two cores)
# make test-all runs every test, the `slow` end-to-end tier too (about 9 min).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# The CPU build of torch, pinned: on Linux PyPI's default build is the multi-GB CUDA one,
# so it comes from PyTorch's CPU index there (macOS's default build is the CPU one). One
# retry: where that index cannot be reached (a machine with a PyPI mirror only) pip falls
# back to its configured sources in seconds, not minutes.
TORCH ?= torch==2.13.0
TORCH_INDEX ?= $(if $(filter Linux,$(shell uname -s)),--index-url https://download.pytorch.org/whl/cpu --retries 1,)
CONFIG ?= spring_fast.yaml
STAMP := $(VENV)/.installed

.PHONY: venv fit test test-all docs lint bench reproduce clean

venv: $(STAMP)

# pip compiles every installed file on one core (over half of its time). Instead torch's
# files compile on a second core while pip installs the rest (pip's install runs on one),
# then the rest on every core. Trees nothing here imports (networkx, which only
# torch.compile loads; pip; setuptools; packages' own tests) are left to compile on first
# import if ever. sympy and mpmath are compiled: `import lightning` loads torch._dynamo and
# with it 470 of their modules, which with PYTHONDONTWRITEBYTECODE set and no bytecode every
# process would compile again. A file written for a newer Python (torch ships one) does
# not compile: pip ignores it, and so does this step (-qq, and its exit status).
# The rest (this package, its extras and their dependencies) by uv: it resolves and
# installs them in about 7 s where pip takes about 60 (pip's resolver judges wheel tags on
# tens of thousands of index links). uv keeps the torch installed above (the range admits
# it) and is not a dependency of the package: where uv cannot be had or cannot reach an
# index, pip installs the same set. `make INSTALLER=pip` skips uv.
INSTALLER ?= uv
PIP_REST = $(BIN)/pip install --quiet --no-compile -e ".[dev,docs]"
UV_REST = $(BIN)/pip install --quiet --no-compile uv && \
	$(BIN)/uv pip install --quiet --python $(BIN)/python -e ".[dev,docs]"
INSTALL_REST = $(if $(filter uv,$(INSTALLER)),{ $(UV_REST) || $(PIP_REST); },$(PIP_REST))
SITE = $(VENV)/lib/python*/site-packages
SKIP = /(networkx|pip|setuptools)/|/tests/
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --no-compile "$(TORCH)" $(TORCH_INDEX)
	{ $(BIN)/python -m compileall -qq -j 1 -x '$(SKIP)' $(SITE)/torch || true; } & \
	$(INSTALL_REST); status=$$?; wait; exit $$status
	$(BIN)/python -m compileall -qq -j 0 -x '$(SKIP)|/site-packages/torch/' $(SITE) || true
	touch $(STAMP)

fit: $(STAMP)
	$(BIN)/python -m hnn_pl fit --config $(CONFIG)

test: $(STAMP)
	$(BIN)/python -m pytest -m "not slow"

test-all: $(STAMP)
	$(BIN)/python -m pytest

# the documentation site (mkdocs.yml: docs/, the API from the docstrings, the results)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --site-dir site

lint: $(STAMP)
	$(BIN)/ruff format --check hnn_pl tests benchmarks examples
	$(BIN)/ruff check hnn_pl tests benchmarks examples

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

reproduce: $(STAMP)
	$(BIN)/python -m hnn_pl reproduce --out RESULTS.md

clean:
	rm -rf $(VENV) lightning_logs .pytest_cache site
