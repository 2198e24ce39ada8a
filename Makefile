# Every target builds or refreshes .venv from the project's own files when they change.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# gymnax declares gymnasium<1.4 (agentax pins 1.4.0) and imports gymnasium only for what agentax does
# not call: installed without its declared dependencies; what it imports is in the lock (extra gymnax).
GYMNAX := gymnax==1.0.1
# jax2onnx declares orbax-checkpoint<0.11.37 (flax wants 0.12) and hub packages it does not import for
# conversion: installed without its declared dependencies too; what it imports is in the lock (extra export).
JAX2ONNX := jax2onnx==0.17.1
# The lock installs with uv (fetching in parallel: about 10 s from an empty cache, pip takes a minute);
# uv is itself one wheel that pip installs into the venv. Bytecode is written as modules are first
# imported, not at install: compiling every installed module (ray, sympy, pandas, PyOpenGL, ...) took
# 22 s of a fresh install on a 2-core AMD EPYC, most of it for modules agentax never imports. The test targets write it even
# where PYTHONDONTWRITEBYTECODE is set (CI machines), so that each process of the suite (each xdist
# worker, each CLI run a test starts, each Ray actor) reads what the first one compiled.
UV := uv==0.13.8
INSTALL := $(VENV)/bin/uv pip install --quiet --python $(PY)
PYTEST := PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -q -n 2 --dist loadgroup

.PHONY: kernel kernel-where-buildable demo test test-quick test-long bench figures lint docs lock clean

# The oneDNN convolution kernel (agentax.kernels): compiled against the onednn wheels of the lock
# (x86-64 Linux), which put libdnnl and its headers under $(VENV)/lib and $(VENV)/include. Where they
# and a compiler are here it must build: a failed build fails the install (and CI). Without them the
# install goes on and says why, agentax uses XLA's convolutions, and make test's summary says so.
CXX ?= g++
KERNEL := src/agentax/_onednn_conv.so
DNNL_LIB := $(abspath $(VENV))/lib

$(STAMP): pyproject.toml requirements.lock csrc/onednn_conv.cc
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet $(UV)
	$(INSTALL) -r requirements.lock
	$(INSTALL) --no-deps $(GYMNAX) $(JAX2ONNX)
	$(INSTALL) --no-deps --no-build-isolation -e .
	$(MAKE) --no-print-directory kernel-where-buildable
	touch $(STAMP)

kernel-where-buildable:
	@if ! test -f $(DNNL_LIB)/libdnnl.so.3 || ! test -f $(VENV)/include/oneapi/dnnl/dnnl.hpp; then \
		echo "agentax: oneDNN kernel not built: no onednn wheels in $(VENV) (the lock has them for x86-64 Linux); convolutions use XLA's"; \
	elif ! command -v $(CXX) >/dev/null 2>&1; then \
		echo "agentax: oneDNN kernel not built: no C++ compiler ($(CXX)); convolutions use XLA's"; \
	else \
		$(MAKE) --no-print-directory kernel; \
	fi

kernel:
	test -f $(DNNL_LIB)/libdnnl.so.3 && test -f $(VENV)/include/oneapi/dnnl/dnnl.hpp
	$(CXX) -O3 -std=c++17 -shared -fPIC -fopenmp -Wno-return-type csrc/onednn_conv.cc -o $(KERNEL).tmp \
		-I$(VENV)/include -I"$$($(PY) -c 'import jax; print(jax.ffi.include_dir())')" \
		-L$(DNNL_LIB) -l:libdnnl.so.3 -Wl,-rpath,$(DNNL_LIB)
	mv $(KERNEL).tmp $(KERNEL)

demo: $(STAMP)
	$(VENV)/bin/agentax demo

test: $(STAMP)
	$(PYTEST) -m "not long"

# The edit-test loop: make test without the slow tests (those that train an agent, compile a whole
# training program, start a process or build the docs site).
test-quick: $(STAMP)
	$(PYTEST) -m "not slow and not long"

# The checks too long for make test (the 100-game backend comparison, the ale-py training smoke run, ...).
test-long: $(STAMP)
	$(PYTEST) -m long

bench: $(STAMP)
	$(PY) benchmarks/run.py

# Every marked figure of the README and the docs printed from its result file (scripts/figures.py);
# make test checks them (tests/test_figures.py).
figures: $(STAMP)
	$(PY) scripts/figures.py --write

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
	.lockenv/bin/pip install --quiet -e '.[dev,atari,ray,sweep,gymnax,onednn,mujoco,export,box2d]' setuptools
	.lockenv/bin/pip freeze --all --exclude-editable | grep -v "^pip==" > requirements.lock
	rm -rf .lockenv

clean:
	rm -rf $(VENV) .pytest_cache .jax_cache $(KERNEL)
