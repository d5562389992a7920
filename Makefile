# Two commands do all set-up on a fresh machine with Python ≥ 3.10:
#   make fit    # venv + install + train the default config (CONFIG=spring_fast.yaml)
#   make test   # venv + install + the whole test suite
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# The CPU build of torch: without the pin pip pulls a multi-GB CUDA build.
TORCH ?= torch==2.13.0
CONFIG ?= spring_fast.yaml
STAMP := $(VENV)/.installed

.PHONY: venv fit test lint bench reproduce clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet "$(TORCH)" -e ".[dev]"
	touch $(STAMP)

fit: $(STAMP)
	$(BIN)/python -m hnn_pl fit --config $(CONFIG)

test: $(STAMP)
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff format --check hnn_pl tests benchmarks examples
	$(BIN)/ruff check hnn_pl tests benchmarks examples

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

reproduce: $(STAMP)
	$(BIN)/python -m hnn_pl reproduce --out RESULTS.md

clean:
	rm -rf $(VENV) lightning_logs .pytest_cache
