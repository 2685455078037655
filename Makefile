# The two commands: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_STAMP := $(VENV)/.installed-runtime
RUN_ARGS ?=

.PHONY: run test lint typecheck bench docs vendor clean

# The project's own modules as bytecode (__pycache__/*.pyc beside them): where
# PYTHONDONTWRITEBYTECODE is set (our image, this kind of CI machine) Python would compile their
# sources again in every process it starts, 0.16 s each for the API and the worker; compileall
# writes only what changed since (0.05 s when nothing did).
BYTECODE := $(BIN)/python -m compileall -q engine service migrations

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# The runtime dependencies only (make run); the test extras (make test) include them.
$(RUN_STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e .
	touch $(RUN_STAMP)

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP) $(RUN_STAMP)

# The service (`spacearm run`): migrate (and compile the kernels on a first run, with progress),
# then the API on $$SPACEARM_HOST:$$SPACEARM_PORT (127.0.0.1:8000) and one worker; the URL is
# printed once the API is ready; Ctrl-C stops both.
# More options: make run RUN_ARGS='--workers 2 --log-format json' (spacearm run --help).
run: $(RUN_STAMP)
	@$(BYTECODE)
	@$(BIN)/spacearm run $(RUN_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check engine service tests bench
	$(BIN)/ruff format --check engine service tests bench

typecheck: $(STAMP)
	$(BIN)/mypy engine service

# The suite runs in TEST_WORKERS processes (pytest-xdist), a test file each at a time: most tests
# wait on servers, workers and jobs of their own. The kernels are compiled once first (if needed).
TEST_WORKERS ?= 2
test: $(STAMP)
	$(BIN)/ruff check engine service tests bench
	$(BIN)/mypy engine service
	$(BIN)/spacearm compile
	$(BYTECODE)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# The reference (docs/) as a static site in var/site; `$(BIN)/mkdocs serve` to read it while editing.
docs: $(STAMP)
	$(BIN)/mkdocs build --strict

# The engine's rows against the anchors, then every goal of issue 21 met or missed in one run
# (start-up, requests, admission, the compiled anchor's kernel goals, memory).
bench: $(STAMP)
	$(BYTECODE)
	$(BIN)/python bench/bench_engine.py
	$(BIN)/python bench/bench_goals.py

# The 3D view's three.js bundle (service/static/three-<version>.min.js), rebuilt from the versions
# pinned by web/package-lock.json (needs Node.js and npm; the test suite checks it with --check).
vendor:
	sh web/build.sh

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
