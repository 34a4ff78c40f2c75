# lunaralbedo: two commands do everything on a fresh machine.
#   make demo   - create .venv, install, run ingest -> solve -> export-kml -> export-web on sample_data/
#   make test   - install the test extras (and Chromium when possible) and run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   := demo_out

.PHONY: demo test browser bench bench-photometry install clean sample-data

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/python tools/run_demo.py --out $(DEMO)

test: $(STAMP) browser
	$(BIN)/python -m pytest -q

# Headless Chromium + chromedriver for the web map's browser tests, from the system package
# manager when they are missing and we may (root + apt-get); otherwise those tests skip with the reason.
browser:
	@command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1 || \
	{ [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; } >/dev/null 2>&1; } || \
	echo "note: chromium/chromedriver not installed (needs root and apt-get); the browser tests will skip"

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

bench-photometry: $(STAMP)
	$(BIN)/python benchmarks/photometry_throughput.py

sample-data: $(STAMP)
	$(BIN)/python tools/make_sample_data.py --out sample_data

clean:
	rm -rf $(DEMO) build *.egg-info .pytest_cache
	find lunaralbedo -name '*.nbi' -o -name '*.nbc' | xargs rm -f  # numba caches (docs/architecture.md)
