# Every target builds or refreshes .venv from the project's own files when they change.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# gymnax declares gymnasium<1.4 (agentax pins 1.4.0) and imports gymnasium only for what agentax does
# not call: installed without its declared dependencies; what it imports is in the lock (extra gymnax).
GYMNAX := gymnax==1.0.1

.PHONY: demo test test-long bench lint docs lock clean

$(STAMP): pyproject.toml requirements.lock
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.lock
	$(PY) -m pip install --quiet --no-deps $(GYMNAX)
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/agentax demo

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadgroup -m "not long"

# The checks too long for make test (the 100-game backend comparison, the ale-py training smoke run, ...).
test-long: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadgroup -m long

bench: $(STAMP)
	$(PY) benchmarks/run.py

# The documentation site (mkdocs.yml) into site/; --strict: a broken link or reference fails.
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict -d site

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/ruff format --check src tests benchmarks

# Re-resolve the pinned dependency set (run by hand after editing pyproject.toml's dependencies).
lock:
	rm -rf .lockenv && $(PYTHON) -m venv .lockenv
	.lockenv/bin/pip install --quiet --upgrade pip
	.lockenv/bin/pip install --quiet -e '.[dev,atari,ray,sweep,gymnax]' setuptools
	.lockenv/bin/pip freeze --all --exclude-editable | grep -v "^pip==" > requirements.lock
	rm -rf .lockenv

clean:
	rm -rf $(VENV) .pytest_cache
