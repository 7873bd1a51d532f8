# Two commands do everything on a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: venv browser demo test test-fast clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

# The browser tests' chromium (tests/integration/test_view.py, zdrone view): installed where it can be
# (root with apt-get, as in CI); elsewhere `make test` runs every other test and shows those as skipped,
# naming the command that installs it. `make demo` needs no browser.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    apt-get update -qq && apt-get install -y -qq chromium; \
	  else \
	    echo "make: no chromium: the browser tests will be skipped (to run them: sudo make browser)"; \
	  fi; }

demo: $(STAMP)
	$(BIN)/zdrone demo $(ARGS)

# The process flights wait on the wall clock (5-6 s of CPU in a 40-50 s flight; the suite uses 0.9 of 2 cores
# at 4 workers): several at once, in workers
# that take the next test when idle; tests sharing one flight get it from tests/procs.py once_per_run
# (and carry the same xdist_group, which keeps them on one worker where pytest-xdist honours it).
# 6 workers: the suite used 1.43 of 2 cores at 5 (813 CPU-s in 567 s); at 6 it ran in 498 s, green.
TEST_WORKERS ?= 6

test: $(STAMP) browser
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --durations=25 $(ARGS)

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup -m 'not slow' $(ARGS)

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
