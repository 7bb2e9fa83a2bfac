# Two entry points: `make demo` (fit, export, validate, diagnose a shipped recording)
# and `make test`. Each creates .venv and installs the project into it through
# constraints.txt (the exact versions the suite last passed with), with uv (the same
# packages as pip's resolver gives under the constraints, in a quarter of the time).
# `make test-newest` runs the suite on the newest versions inside pyproject.toml's ranges.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
OUT := out

$(BIN)/duhem: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q uv==0.13.10
	$(BIN)/uv pip install -q --python $(BIN)/python -c constraints.txt ".[test]"
	touch $(BIN)/duhem

.PHONY: install demo test test-slow test-newest bench
install: $(BIN)/duhem

demo: install
	mkdir -p $(OUT)
	$(BIN)/duhem fit examples/demo.csv -o $(OUT)/demo.json --fmu $(OUT)/demo.fmu
	$(BIN)/duhem validate $(OUT)/demo.fmu examples/demo.csv --plot $(OUT)/demo_validate.png
	$(BIN)/duhem diagnose examples/diagnose/*.csv --report $(OUT)/diagnose --json $(OUT)/diagnose.json

test: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -q -n 2 --dist worksteal --durations=20 -m "not slow"

test-slow: install
	$(BIN)/python -m pytest -q -n 2 --dist worksteal -m slow

test-newest:
	rm -rf .venv-newest
	$(PYTHON) -m venv .venv-newest
	.venv-newest/bin/pip install -q --upgrade pip
	.venv-newest/bin/pip install -q --upgrade ".[test]"
	.venv-newest/bin/pip freeze --exclude semilinear-duhem | grep -iE "^(numpy|scipy|cvxpy|fmpy|pythonfmu)=="
	.venv-newest/bin/ruff check .
	.venv-newest/bin/python -m pytest -q -n 2

bench: install
	$(BIN)/python bench/reproduce_paper.py
	$(BIN)/python bench/fmu_throughput.py
	$(BIN)/python bench/real_data.py
	$(BIN)/python bench/real_fit_speed.py
	$(BIN)/python bench/effect_fit_speed.py
	$(BIN)/python bench/diagnose_generality.py
	$(BIN)/python bench/export_agreement.py
	$(BIN)/python bench/compensation.py
	$(BIN)/python bench/other_systems.py
	$(BIN)/python bench/batch.py
	$(BIN)/python bench/long_recordings.py
	$(BIN)/python bench/export_platforms.py
	$(BIN)/python bench/speed_summary.py --out out/bench/speed.md
