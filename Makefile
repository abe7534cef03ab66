# mlnseq: set-up, tests, benchmarks and the paper's reproduction.
.DEFAULT_GOAL := help
SHELL := /bin/bash

VENV := .venv
PY := $(VENV)/bin/python
MLNSEQ := $(VENV)/bin/mlnseq
SETUP_DONE := $(VENV)/.setup-done

.PHONY: help setup test bench reproduce clean

help: ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  %-12s %s\n", $$1, $$2}'

setup: $(SETUP_DONE) ## Create .venv with mlnseq, its test dependencies and pracmln

$(SETUP_DONE): pyproject.toml scripts/setup.sh scripts/install_pracmln.sh
	bash scripts/setup.sh

test: setup ## Run the test suite
	$(VENV)/bin/pytest -q

bench: setup ## Run the benchmarks (figures and ratios measured side by side)
	$(PY) -m benchmarks

reproduce: setup ## Rebuild the paper's results from the real data
	$(MLNSEQ) collect --env desk --source $(DESK_DIR) --workdir runs/desk

DESK_DIR ?= ../shared/data/desk-taurus

clean: ## Remove generated workdirs and reports (keeps .venv)
	rm -rf runs reports mlnseq-work
