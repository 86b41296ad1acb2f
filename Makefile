# Two entry points: `make demo` and `make test`. Both create .venv when missing
# and install the project (editable, with test extras) into it.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-cases test-deep coverage lint bench benchmarks docs docs-images clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $(STAMP)

# The main job on the simulated robot: the dry run (the controller in the loop with the
# simulated ROCASPECT along the paper's centre path), then the model, a campaign on the
# plant with the paper's concealed effects, its blind diagnosis, then the paper's own data.
DEMO := out/demo
demo: $(STAMP)
	@echo "== dry run of the paper's centre path: recording in $(DEMO)/dryrun, plots in $(DEMO)/dryrun_plots"
	$(VENV)/bin/cdpr dry-run paper-centre --record $(DEMO)/dryrun --force --plots $(DEMO)/dryrun_plots
	$(VENV)/bin/cdpr model check rocaspect --plots $(DEMO)
	$(VENV)/bin/cdpr campaign bench/data/paper_scenario.toml $(DEMO)/recording --force
	$(VENV)/bin/cdpr diagnose $(DEMO)/recording --plots $(DEMO)/plots --write-model $(DEMO)/corrected.toml --out $(DEMO)/report.json
	@echo "== the scenario's concealed truth beside what the diagnosis found (it never read the scenario)"
	$(VENV)/bin/cdpr compare bench/data/paper_scenario.toml $(DEMO)/report.json
	$(VENV)/bin/cdpr diagnose examples/paper_tables --plots $(DEMO)/paper_plots

# Two test processes (this machine and CI have 2 cores), one file per process at a time so
# that a module's fixtures are computed once.
test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile --durations=15

# Single hard evaluation cases recorded and diagnosed (marker `cases`, 20-60 s each, left out of
# `make test` to keep it under 10 minutes); CI runs them after `make test`.
test-cases: $(STAMP)
	$(PY) -m pytest -q -n 2 -m cases --durations=5

# The coverage of the diagnosis's 95 % intervals per effect kind of the vocabulary, every kind
# on its recording classes (marker `coverage`, left out of `make test`; ~20 CPU-min).
# docs/guide/diagnosis-report.md
coverage: $(STAMP)
	$(PY) -m pytest -q -n 2 -m coverage --durations=0 tests/test_diagnosis_intervals.py

# The property-based tests with many more examples (tests/conftest.py, profile "deep";
# tests/prop_support.py: 5 times the state machines' examples, twice their steps), with
# hypothesis' statistics (the events each rule reached). docs/guide/property-tests.md
test-deep: $(STAMP)
	CDPR_HYPOTHESIS=deep $(PY) -m pytest -q -n 2 --dist loadfile --hypothesis-show-statistics \
		tests/test_prop_cia402_drive.py tests/test_prop_supervisor.py tests/test_prop_loop.py \
		tests/test_prop_hal_drives.py tests/test_input_files.py tests/test_fuzz_can_modbus.py \
		tests/test_dryrun_properties.py

lint: $(STAMP)
	$(VENV)/bin/ruff check .

bench: $(STAMP)
	$(VENV)/bin/cdpr bench

# The documentation's benchmarks page, generated (never edited by hand). BENCH picks a
# subset, e.g. make benchmarks BENCH='--only physics'.
BENCH ?=
benchmarks: $(STAMP)
	@mkdir -p out
	$(VENV)/bin/cdpr bench $(BENCH) --json > out/bench.json
	$(PY) -m bench.benchmarks.page out/bench.json --out docs/benchmarks.md

# The documentation site (MkDocs, Material theme) in site/; warnings are errors.
docs: $(STAMP)
	$(PY) -m mkdocs build --strict

# The documentation's pictures: a short dry run's path plot and the frames figure.
docs-images: $(STAMP)
	$(VENV)/bin/cdpr dry-run paper-centre --duration 20 --plots out/docs_dryrun
	cp out/docs_dryrun/path.png docs/img/dry-run.png
	$(PY) docs/tools/frames_figure.py docs/img/frames.png

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache site
