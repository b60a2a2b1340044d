# resti: `make help` lists the targets.
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PARAMS ?= params/default.yaml

.PHONY: help venv report reoption test bench bench-scale screenshot lint clean strip-notebooks

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 --display-name "Python 3 (resti)" >/dev/null
	touch $(STAMP)

venv: $(STAMP)  ## create .venv and install resti with its dependencies

report: $(STAMP)  ## main job: mini-world (if absent) -> task notebooks -> release, tables, figures, HTML report
	$(BIN)/resti run --params $(PARAMS)

reoption: $(STAMP)  ## rebuild the options of the public ReSTI v5 release (notebook 90) and re-index the report
	$(BIN)/resti run --params $(PARAMS) --only 90_reoption_release

test: $(STAMP)  ## run the test suite (real-data tests need ../shared or RESTI_SHARED)
	$(BIN)/python -m pytest -q

bench: $(STAMP)  ## speed benchmarks (ratios and throughput): answer interface, sources, default run
	$(BIN)/python -m bench

bench-scale: $(STAMP)  ## scale benchmark: the 2,064-row structure and 100x (about 206k rows, ~10 min)
	$(BIN)/python -m bench bench_scale

screenshot: $(STAMP)  ## render outputs/report/index.html in headless Chromium and save a PNG
	$(BIN)/python -m bench.screenshot

lint: $(STAMP)  ## ruff
	$(BIN)/ruff check resti_lib tests bench

strip-notebooks: $(STAMP)  ## remove outputs from committed notebooks
	$(BIN)/python -m resti_lib.runner --strip notebooks/*.ipynb

clean:  ## remove generated outputs (keeps .venv)
	rm -rf outputs/* && touch outputs/.gitkeep
