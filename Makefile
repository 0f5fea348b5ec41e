# Two commands for a newcomer: `make report` and `make test`. Both build .venv from scratch if needed.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
REPORTS ?= reports

.PHONY: report test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

report: $(STAMP)
	$(BIN)/python studies/calibrate_needle_208.py --out $(REPORTS) --data $(REPORTS)/needle_208/calibrated_geometry.json
	$(BIN)/python studies/needle_208_nominal.py --out $(REPORTS)
	$(BIN)/python studies/needle_208_tolerances.py --out $(REPORTS) --n-jobs 2 --progress
	$(BIN)/python studies/feed_131_report.py --out $(REPORTS) --n-jobs 2 --progress

test: $(STAMP)
	$(BIN)/ruff check src tests studies $(wildcard benchmarks)
	$(BIN)/python -m pytest -q

# The benchmarks run in their own venv so the peer (pylinkage) is never a dependency of sewtol.
BENCH := .venv-bench
$(BENCH)/.installed: pyproject.toml
	$(PYTHON) -m venv $(BENCH)
	$(BENCH)/bin/python -m pip install --quiet --upgrade pip
	$(BENCH)/bin/python -m pip install --quiet -e . "pylinkage>=1.3"
	touch $@

bench: $(BENCH)/.installed
	$(BENCH)/bin/python benchmarks/throughput.py --json
	$(BENCH)/bin/python benchmarks/studies.py --json

clean:
	rm -rf $(VENV) $(BENCH) .pytest_cache .hypothesis build src/*.egg-info
