# bodyhealth — the two commands: `make run` and `make test`.
PY      ?= python3.11
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
PORT    ?= 8000
# pytest-xdist worker processes for `make test` (tests are grouped by file: a module's fixtures are
# built once); 2 fits the 2-core machines the suite's time bound is stated for
TEST_WORKERS ?= 2

.PHONY: setup setup-browser run test test-fast coverage lint bench docs clean

## setup: create .venv/ and install the project with its dev tools (quick when nothing changed)
setup: $(STAMP)

$(STAMP): pyproject.toml $(wildcard */__init__.py)
	@test -x $(BIN)/python || $(PY) -m venv $(VENV) || python3 -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP)

## setup-browser: Debian's Chromium + ChromeDriver for the dashboard tests (root, apt)
setup-browser:
	@if ! command -v chromium >/dev/null 2>&1; then \
	  echo "installing chromium (Debian package) for the browser tests"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null) \
	  || echo "warning: could not install chromium; browser tests will be skipped"; \
	fi

## run: the service with an embedded SQLite store and a simulated robot farm; dashboard on localhost
run: setup
	$(BIN)/bodyhealth serve --demo --port $(PORT)

## test: set up, lint, and run every test (slow ones included)
test: setup setup-browser lint
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=15

## test-fast: skip the slow and end-to-end tests while developing
test-fast: setup
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not slow and not e2e"

## coverage: every test, with the line coverage of the science and service packages (coverage.json);
## the services the end-to-end tests start in processes of their own are not counted
coverage: setup setup-browser
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --cov=bodyschema --cov=simulators \
	  --cov=service --cov-report=term:skip-covered --cov-report=json:coverage.json

## lint: ruff (style, plus the size rules: C901 branches, PLR0915 statements) and the import layers
lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

## bench: every benchmark; results go to docs/bench/
bench: setup
	$(BIN)/bodyhealth bench all

## docs: rewrite the figures quoted in README.md and docs/*.md from the bench files in docs/bench/
docs: setup
	$(BIN)/bodyhealth bench docs

clean:
	rm -rf $(VENV) var .pytest_cache .ruff_cache .hypothesis
