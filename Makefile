# enclab: two commands on a fresh clone with python3 + pip: `make run`, `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
CORES  ?= 2
# Config overrides and extra snakemake arguments, e.g.
#   make run CONFIG='manifest=data/manifest.real.yaml'   make run SMK_ARGS='--dry-run'
CONFIG   ?=
SMK_ARGS ?=
# Snakemake finds a default profile only next to the Snakefile, so ours is named.
PROFILE := --workflow-profile workflow/profiles/default
STAMP  := $(VENV)/.installed
SLURM_STAMP := $(VENV)/.installed-slurm

.PHONY: run test test-fast test-slurm report lint clean venv venv-slurm

venv: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@echo "==> creating $(VENV) and installing pinned dependencies (constraints.txt)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --progress-bar on -c constraints.txt -e '.[test]'
	@touch $@

# The SLURM executor plugin (pip extra [slurm]), only for cluster runs and test-slurm.
venv-slurm: $(SLURM_STAMP)

$(SLURM_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[test,slurm]'
	@touch $@

# The terminal shows one line per finished job and one per failure (--logger enclab, see
# workflow/enclab/progress.py; Snakemake's full log: .snakemake/log/). A log that fails (bad
# input) stops only itself: --keep-going (in the profile) finishes the others, then a second
# pass builds the batch tables, figures, run summary and report from the logs that completed,
# and make exits non-zero so the failure is not missed. The run summary (what ran, the headline
# numbers, what failed and why: results/summary.txt) closes the output.
SMK := $(BIN)/snakemake $(PROFILE) --logger enclab
REPORT := $(SMK) --cores 1 --report results/report.html \
	--report-metadata results/report/metadata.yaml --report-stylesheet workflow/report/report.css

run: $(STAMP)
	@echo "==> running the workflow: config.yaml$(if $(CONFIG), + $(CONFIG),, the embedded default), $(CORES) cores"
	@status=0; scope=all; \
	if $(SMK) --cores $(CORES) --config batch_scope=all $(CONFIG) $(SMK_ARGS); then \
		done=1; \
	else \
		echo "==> some logs failed (above); batch tables, summary and report from the rest"; \
		status=1; scope=completed; done=0; \
		$(SMK) --cores $(CORES) --config batch_scope=completed $(CONFIG) $(SMK_ARGS) && done=1; \
	fi; \
	if [ $$done = 1 ]; then \
		$(REPORT) --config batch_scope=$$scope $(CONFIG) $(SMK_ARGS) || status=1; \
		if [ -f results/summary.txt ]; then echo "==> run summary (results/summary.txt)"; cat results/summary.txt; fi; \
		if [ -f results/report.html ]; then echo "==> report: results/report.html ($$(du -h results/report.html | cut -f1))"; fi; \
	else \
		echo "==> the batch pass failed too (above): no run summary, no report"; \
	fi; \
	exit $$status

# The HTML report of the last run (make run builds it too).
report: $(STAMP)
	$(REPORT) $(if $(CONFIG),--config $(CONFIG)) $(SMK_ARGS)

test: $(STAMP)
	@echo "==> running the test suite"
	$(BIN)/python -m pytest -v --durations=15

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

# Opt-in, needs root: installs Debian's SLURM and MariaDB packages, starts a one-node cluster on
# localhost, runs the workflow through --executor slurm, compares with a local run, stops the
# cluster (docs/cluster.md). Not part of `make test` or CI.
test-slurm: $(SLURM_STAMP)
	bash .ci/slurm/test.sh

lint: $(STAMP)
	$(BIN)/snakemake --lint 2>&1 | grep -v -i conda || true

clean:
	rm -rf results .snakemake
