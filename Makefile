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

# A log that fails (bad input) stops only itself: --keep-going finishes the others, then a second
# pass builds the batch tables, figures and report from the logs that completed, and make exits
# non-zero so the failure is not missed (each failed log's reason: results/<log_id>/logs/).
run: $(STAMP)
	@echo "==> running the workflow on the embedded default (config.yaml, $(CORES) cores)"
	@if $(BIN)/snakemake $(PROFILE) --cores $(CORES) --printshellcmds --keep-going $(if $(CONFIG),--config $(CONFIG)) $(SMK_ARGS); then \
		$(BIN)/snakemake $(PROFILE) --cores 1 --report results/report.html $(if $(CONFIG),--config $(CONFIG)) $(SMK_ARGS) && \
		echo "==> done: results/ (summaries, batch tables, figures) and results/report.html"; \
	else \
		echo "==> some logs failed (messages above); batch tables and report from the rest"; \
		$(BIN)/snakemake $(PROFILE) --cores $(CORES) --keep-going --config batch_scope=completed $(CONFIG) $(SMK_ARGS) && \
		$(BIN)/snakemake $(PROFILE) --cores 1 --report results/report.html --config batch_scope=completed $(CONFIG) $(SMK_ARGS); \
		exit 1; \
	fi

test: $(STAMP)
	@echo "==> running the test suite"
	$(BIN)/python -m pytest -v --durations=15

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

# Opt-in, needs root: installs Debian's SLURM and MariaDB packages, starts a one-node cluster on
# localhost, runs the workflow through --executor slurm, compares with a local run, stops the
# cluster (README "Running on a cluster (SLURM)"). Not part of `make test` or CI.
test-slurm: $(SLURM_STAMP)
	bash .ci/slurm/test.sh

lint: $(STAMP)
	$(BIN)/snakemake --lint 2>&1 | grep -v -i conda || true

clean:
	rm -rf results .snakemake
