# resti: `make help` lists the targets.
PY ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PARAMS ?= params/default.yaml
PIP := $(BIN)/pip --disable-pip-version-check -q
# `make report FORCE=1` reruns every stage (default: only the stages whose inputs, params or code changed)
# `make report BASELINE=1` makes this run the baseline of the report's What changed section
RUN_FLAGS := $(if $(FORCE),--force,) $(if $(BASELINE),--baseline,)

.PHONY: help venv report reoption test test-fast bench bench-scale screenshot browser lint clean strip-notebooks

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@echo "resti: creating $(VENV) with $(PY)"
	@$(PY) -m venv $(VENV)
	@echo "resti: installing resti and its dependencies into $(VENV) (pip, 1-3 minutes) ..."
	@$(PIP) install --upgrade pip
	@PYTHONWARNINGS=ignore::UserWarning $(PIP) install --progress-bar off -e '.[dev]'  # no editable-mode banners
	@echo "resti: registering the notebook kernel"
	@$(BIN)/python -m ipykernel install --sys-prefix --name python3 --display-name "Python 3 (resti)" >/dev/null
	@touch $(STAMP)
	@echo "resti: ready ($(VENV)); next: make report"

venv: $(STAMP)  ## create .venv and install resti with its dependencies

report: $(STAMP)  ## main job: reruns the stages that changed (FORCE=1: all) -> release, tables, figures, HTML report
	@$(BIN)/resti run --params $(PARAMS) $(RUN_FLAGS)

reoption: $(STAMP)  ## rebuild the options of the public ReSTI v5 release (notebook 90) and re-index the report
	@$(BIN)/resti run --params $(PARAMS) --only 90_reoption_release $(RUN_FLAGS)

# tests run on every core; the tests of the shared main-job run stay on one worker (conftest.py)
TEST_JOBS ?= auto
test: $(STAMP) browser  ## the full test suite, as CI runs it (real data: ../shared or RESTI_SHARED; installs chromium if it can)
	$(BIN)/python -m pytest -q -n $(TEST_JOBS) --dist loadgroup

test-fast: $(STAMP)  ## the edit loop: every test but notebooks, the main job, long checks on the real data and end-to-end checks over 3 s (make test runs all)
	$(BIN)/python -m pytest -q -x -n $(TEST_JOBS) --dist worksteal -m "not notebook and not slow and not shared"

bench: $(STAMP)  ## speed benchmarks (ratios and throughput): answer interface, sources, make report cold/warm/one task
	$(BIN)/python -m bench

bench-scale: $(STAMP)  ## scale benchmark: the 2,064-row structure and 100x (about 206k rows, ~10 min)
	$(BIN)/python -m bench bench_scale

screenshot: $(STAMP)  ## render outputs/report/index.html in headless Chromium, full page, to a PNG
	@$(BIN)/python -m bench.screenshot

browser:  ## install headless Chromium (Debian, as root) for the report's browser test and `make screenshot`
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  { echo "resti: installing chromium (apt-get) for the browser test ..."; \
	    DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1 || \
	    { apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1; } || \
	    echo "resti: chromium could not be installed; the browser test skips (and fails under CI=true)" >&2; }

lint: $(STAMP)  ## ruff
	$(BIN)/ruff check resti_lib tests bench

strip-notebooks: $(STAMP)  ## remove outputs from committed notebooks
	$(BIN)/python -m resti_lib.run.notebooks --strip notebooks/*.ipynb

clean:  ## remove generated outputs (keeps .venv)
	rm -rf outputs/* outputs/.resti && touch outputs/.gitkeep
