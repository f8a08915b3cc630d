# The two set-up commands of the README: `make demo` and `make test`.
# Both create .venv if it is missing and install the package into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(PY) pyproject.toml
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# the demo's files go to ./demo_out (overwritten each run); `make demo DEMO_OUT=DIR` picks another
DEMO_OUT ?= demo_out

demo: $(STAMP)
	$(VENV)/bin/calib-oed demo -o $(DEMO_OUT)

# one pytest worker per core, at most 4 (pytest-xdist), each single-threaded BLAS so the workers do not
# oversubscribe the cores; `pytest` alone runs the suite serially
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest -q -n auto --maxprocesses 4 --dist worksteal

lint: $(STAMP)
	$(VENV)/bin/ruff check calib_oed tests bench examples

bench: $(STAMP)
	$(PY) bench/bench_jacobian.py

clean:
	rm -rf $(VENV) build *.egg-info
