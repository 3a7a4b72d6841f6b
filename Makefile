# The two set-up commands of the README: `make run` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: run test install install-test clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# `railstop compile` fills the on-disk cache of the compiled stop model once
# (tens of seconds on a fresh install; a moment when it is already there).
install: $(BIN)/python
	$(BIN)/python -m pip install -q -e .
	$(BIN)/railstop compile

install-test: $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[test]'
	$(BIN)/railstop compile

# The main job on the embedded default data.
run: install
	$(BIN)/railstop demo

# Lint, type check and the whole test suite.
test: install-test
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy src
	$(BIN)/pytest -q -n 2

clean:
	rm -rf $(VENV) railstop-demo railstop.db .pytest_cache .ruff_cache .hypothesis
