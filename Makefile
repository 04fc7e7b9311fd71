# Set-up and entry points. `make demo` and `make test` create .venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.installed

.PHONY: demo lint test test-slow fuzz fuzz-c3d bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip
	# CPU build of torch first: an unpinned torch would pull several GB of CUDA wheels.
	$(PIP) install "torch==2.13.0"
	$(PIP) install -e ".[test,opensim,bench]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/spinemocap demo --out demo_out

# lint (ruff: pyflakes, bugbear, isort) and type check (mypy), configured in pyproject.toml
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

test: $(STAMP) lint
	$(PY) -m pytest

test-slow: $(STAMP)
	$(PY) -m pytest -m slow

# Every reader fuzzed at scale: >= 10,000 damaged files per format (SPINEMOCAP_FUZZ_CASES for more)
fuzz: $(STAMP)
	$(PY) -m pytest -m slow -s tests/test_fuzz_readers.py tests/exporters/test_c3d_fuzz.py

# C3D reader fuzzing at scale: 10,000 damaged small files + 500 damaged Nexus files
fuzz-c3d: $(STAMP)
	$(PY) -m pytest -m slow -s tests/exporters/test_c3d_fuzz.py

clean:
	rm -rf $(VENV) demo_out
