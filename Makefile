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

# The test modules that mostly wait on the wall clock (live processes at a time scale, the attacks
# on the live line; about a third of a core): one pytest of their own, one test after another, beside the two workers of the
# compute-bound rest, so that their waiting overlaps the computing. Both must pass. The rest runs
# at a lower priority (nice 10), as a wayside computer would run batch work beside its safety
# processes: the live processes keep their periods; the live tests still hold on a loaded machine
# (``pytest --busy 2``), but a scheduler stall of a second would make them test the stall.
WALL_CLOCK_TESTS = tests/e2e/test_live.py tests/e2e/test_control_room.py tests/e2e/test_live_attack.py tests/live/test_live_plant.py

# Lint, type check and the whole test suite.
test: install-test
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy src
	@log=$$(mktemp); \
	$(BIN)/pytest -q -p no:cacheprovider $(WALL_CLOCK_TESTS) >"$$log" 2>&1 & wall=$$!; \
	nice -n 10 $(BIN)/pytest -q -n 2 --durations=25 $(addprefix --ignore=,$(WALL_CLOCK_TESTS)); rest=$$?; \
	wait $$wall; walled=$$?; \
	echo "--- the wall-clock tests ($(WALL_CLOCK_TESTS)), run beside the rest:"; cat "$$log"; rm -f "$$log"; \
	test $$rest -eq 0 && test $$walled -eq 0

clean:
	rm -rf $(VENV) railstop-demo railstop.db railstop.db.zc-state .pytest_cache .ruff_cache .hypothesis
