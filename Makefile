# Two commands for a newcomer: `make report` and `make test`. Both build .venv from the committed
# lock (requirements.lock: exact versions and hashes for every platform and Python >= 3.11).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
LOCK := requirements.lock
# `make report TOLERANCES=my.toml` (or my.toml:SET) studies the needle with your own tolerance
# sets and writes into reports-custom/ unless REPORTS says otherwise, so the committed reports
# stay as they are
TOLERANCES ?=
ifeq ($(strip $(TOLERANCES)),)
REPORTS ?= reports
else
REPORTS ?= reports-custom
endif
FIGURE_FORMAT ?= png
# the narrowed CPU dispatch under which CI repeats the numerically sensitive tests: another
# OpenBLAS kernel set, numpy's SIMD dispatch without AVX-512, numba compiled for a generic CPU
NARROWED := OPENBLAS_CORETYPE=Prescott NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" \
	NUMBA_CPU_NAME=generic

.PHONY: report test test-narrowed test-latest lint bench lock validate clean docs kernels

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml setup.py $(LOCK) | $(BIN)/python
	$(BIN)/python -m pip install --quiet --require-hashes -r $(LOCK)
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(STAMP)

# The needle kernels a Monte-Carlo and the strategies study call, compiled ahead of time (numba.pycc,
# from the same Python functions) into an extension module beside them, so a short `needle
# montecarlo` and every worker of `needle strategies` run without importing numba; its name holds a digest of the kernels' sources and the numba and numpy
# versions, so this rebuilds it only when one of those changed (and a stale one is never loaded).
# Without a C compiler it is not built and says so: numba's kernels then run (the same bits, a
# slower start); CI sets SEWTOL_REQUIRE_AHEAD=1 so tests/test_ahead.py fails instead of skipping
kernels: $(STAMP)
	$(BIN)/python -c "from sewtol.mechanisms.needle_208.kernels import build; build()" \
		|| echo "make kernels: the needle kernels are not compiled ahead of time (see the error" \
			"above; needs gcc): numba's kernels run instead, same results, slower start" >&2

# Reports come from the frames shipped as package data (never refitted here) and name the
# revision they were made from: the package is reinstalled first so run.json records it.
report: $(STAMP) kernels
	$(BIN)/python -m pip install --quiet --no-deps -e .
ifeq ($(strip $(TOLERANCES)),)
	$(BIN)/python studies/calibrate_needle_208.py --stored --out $(REPORTS)
	$(BIN)/python studies/needle_208_nominal.py --out $(REPORTS) --figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_tolerances.py --out $(REPORTS) --n-jobs 2 --progress \
		--figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_frames.py --out $(REPORTS) --n-mc 10000 --n-sobol 1024 \
		--n-jobs 2 --progress --figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_ppm.py --out $(REPORTS) --n-jobs 2 --progress \
		--figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_strategies.py --out $(REPORTS) --n 2000 --n-jobs 2 \
		--figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_strategies_frames.py --out $(REPORTS) --n 500 --n-jobs 2
	$(BIN)/python studies/needle_208_measurement.py --out $(REPORTS) --n 500 --n-jobs 2 \
		--figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_housing.py --out $(REPORTS) --n-jobs 2
	$(BIN)/python studies/needle_208_joint.py --out $(REPORTS)
	$(BIN)/python studies/needle_208_clearances.py --out $(REPORTS) --n 400
	$(BIN)/python studies/needle_208_index.py --out $(REPORTS)
	$(BIN)/python studies/feed_131_report.py --out $(REPORTS) --n-jobs 2 --progress \
		--figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/feed_131_clearances.py --out $(REPORTS)
	$(BIN)/python studies/m6_needle_report.py --out $(REPORTS)
	$(BIN)/python studies/presser_foot_report.py --out $(REPORTS)
	$(BIN)/python -m sewtol run spatial_crank_rocker report --seed 2026 \
		--out $(REPORTS)/spatial_crank_rocker
	$(BIN)/python -m sewtol run spatial_crank_slider report --seed 2026 \
		--out $(REPORTS)/spatial_crank_slider
	$(BIN)/python -m sewtol run khujand_feed report --seed 2026 --out $(REPORTS)/khujand_feed
else
	$(BIN)/python studies/needle_208_nominal.py --out $(REPORTS) --figure-format $(FIGURE_FORMAT)
	$(BIN)/python studies/needle_208_tolerances.py --out $(REPORTS) --n-jobs 2 --progress \
		--figure-format $(FIGURE_FORMAT) --tolerances $(TOLERANCES)
	$(BIN)/python studies/needle_208_strategies.py --out $(REPORTS) --n 2000 --n-jobs 2 \
		--figure-format $(FIGURE_FORMAT) --tolerances $(TOLERANCES)
	$(BIN)/python studies/needle_208_strategies_frames.py --out $(REPORTS) --n 500 --n-jobs 2 \
		--tolerances $(TOLERANCES)
	$(BIN)/python studies/needle_208_index.py --out $(REPORTS)
endif

lint: $(STAMP)
	$(BIN)/ruff check src tests studies examples $(wildcard benchmarks)

test: lint kernels
	$(BIN)/python -m pytest -q

# the numerically sensitive tests again, under another CPU's kernels (see docs/reproducibility.md)
test-narrowed: $(STAMP) kernels
	$(NARROWED) $(BIN)/python -m pytest -q -m numerics -p no:cacheprovider

# the suite against the newest versions pyproject.toml allows (no lock): warns of a breaking
# release the day it appears; CI runs it without letting it block the locked run
LATEST := .venv-latest
test-latest:
	rm -rf $(LATEST)
	$(PYTHON) -m venv $(LATEST)
	$(LATEST)/bin/python -m pip install --quiet --upgrade pip
	$(LATEST)/bin/python -m pip install --quiet --upgrade -e ".[test]"
	$(LATEST)/bin/python -m pip list --format=freeze | grep -iE '^(numpy|scipy|pandas|numba|salib|joblib|distributed)=='
	$(LATEST)/bin/python -m pytest -q -p no:cacheprovider

# The documentation site: the user guide (docs/*.md) and the API reference built from the
# docstrings (docs/api/*.md), into site/. --strict turns every warning into a failure: a broken
# link between pages, a missing anchor, a ::: reference to a name that does not exist. The docs
# tools (the `docs` extra) come from the same hash-checked lock as everything else.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --site-dir site

# refresh the lock: uv resolves once for every platform and Python >= 3.11 (one version of each
# package where possible); pip installs it with hash checking, so users need no extra tool
lock:
	$(PYTHON) -m venv .venv-lock
	.venv-lock/bin/python -m pip install --quiet uv==0.13.8
	.venv-lock/bin/uv pip compile pyproject.toml --extra test --extra docs --universal \
		--python-version 3.11 --fork-strategy fewest --generate-hashes -o $(LOCK)

# The benchmarks run in their own venv so the peer (pylinkage) is never a dependency of sewtol.
BENCH := .venv-bench
$(BENCH)/.installed: pyproject.toml $(LOCK)
	$(PYTHON) -m venv $(BENCH)
	$(BENCH)/bin/python -m pip install --quiet --upgrade pip
	$(BENCH)/bin/python -m pip install --quiet --require-hashes -r $(LOCK)
	$(BENCH)/bin/python -m pip install --quiet --no-deps -e .
	$(BENCH)/bin/python -m pip install --quiet "pylinkage==1.3.*"
	touch $@

bench: $(BENCH)/.installed
	$(BENCH)/bin/python -c "from sewtol.mechanisms.needle_208.kernels import build; build()"
	$(BENCH)/bin/python benchmarks/throughput.py --json
	$(BENCH)/bin/python benchmarks/studies.py --json
	$(BENCH)/bin/python benchmarks/generic_vs_fused.py --json
	$(BENCH)/bin/python benchmarks/cli.py --json

clean:
	rm -rf $(VENV) $(BENCH) $(LATEST) .venv-lock .pytest_cache .hypothesis build site src/*.egg-info \
		src/sewtol/mechanisms/needle_208/kernels/ahead_*

# the exact optimiser against a dense brute force on the 10,000 seed-2026 recommended-set
# machines (beta alone, then beta + guide shift); about 10 min each on 2 cores
validate: $(STAMP)
	$(BIN)/python benchmarks/validate_adjust.py
	$(BIN)/python benchmarks/validate_adjust.py --shift
