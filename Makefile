# enclab: two commands on a fresh clone with python3 + pip: `make run`, `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
CORES  ?= 2
STAMP  := $(VENV)/.installed

.PHONY: run test test-fast report lint clean venv

venv: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@echo "==> creating $(VENV) and installing pinned dependencies (constraints.txt)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --progress-bar on -c constraints.txt -e '.[test]'
	@touch $@

run: $(STAMP)
	@echo "==> running the workflow on the embedded default (config.yaml, $(CORES) cores)"
	$(BIN)/snakemake --cores $(CORES) --printshellcmds --keep-going
	$(BIN)/snakemake --cores 1 --report results/report.html
	@echo "==> done: results/ (summaries, batch tables, figures) and results/report.html"

test: $(STAMP)
	@echo "==> running the test suite"
	$(BIN)/python -m pytest -v --durations=15

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

lint: $(STAMP)
	$(BIN)/snakemake --lint 2>&1 | grep -v -i conda || true

clean:
	rm -rf results .snakemake
