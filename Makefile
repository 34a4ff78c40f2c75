# lunaralbedo: two commands do everything on a fresh machine.
#   make demo   - create .venv, install, run ingest -> solve -> export-kml on sample_data/
#   make test   - install the test extras and run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   := demo_out

.PHONY: demo test bench bench-photometry install clean sample-data

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/python tools/run_demo.py --out $(DEMO)

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

bench-photometry: $(STAMP)
	$(BIN)/python benchmarks/photometry_throughput.py

sample-data: $(STAMP)
	$(BIN)/python tools/make_sample_data.py --out sample_data

clean:
	rm -rf $(DEMO) build *.egg-info .pytest_cache
