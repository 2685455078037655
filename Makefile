# The two commands: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint typecheck bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The service: migrate, then the API on 127.0.0.1:8000 and one worker; Ctrl-C stops both.
run: $(STAMP)
	$(BIN)/spacearm migrate
	@trap 'kill $$api $$worker 2>/dev/null; wait $$api $$worker 2>/dev/null; exit 0' INT TERM; \
	SPACEARM_HOST=127.0.0.1 SPACEARM_PORT=8000 $(BIN)/spacearm serve & api=$$!; \
	$(BIN)/spacearm worker & worker=$$!; \
	echo "spacearm API on http://127.0.0.1:8000 (docs at /docs), worker pid $$worker; Ctrl-C stops both"; \
	wait $$api $$worker

lint: $(STAMP)
	$(BIN)/ruff check engine service tests bench
	$(BIN)/ruff format --check engine service tests bench

typecheck: $(STAMP)
	$(BIN)/mypy engine service

test: $(STAMP)
	$(BIN)/ruff check engine service tests bench
	$(BIN)/mypy engine service
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python bench/bench_engine.py

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
