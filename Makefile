# The README's two commands. Each sets itself up (virtualenv, install) on first use.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
OUT ?= results/gaits

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/spikejax reproduce gaits --out $(OUT)
	$(VENV)/bin/spikejax reproduce gait-choices --out $(OUT)

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -m "not slow" -n auto --maxprocesses 4 --dist loadfile

bench: $(STAMP)
	$(VENV)/bin/spikejax bench gaits

clean:
	rm -rf $(VENV) results
