#!/usr/bin/env bash
# `make test-slurm`: run the embedded default through a real one-node SLURM cluster and check
# that the results equal a local run. Opt-in (root, apt-get, daemons); `.ci/run` does not call it.
#
#   SLURM_TEST_LOGS  comma-separated log ids of data/manifest.yaml, or "all" (default: a subset
#                    that covers every rule: two Fig. 7 repeats, one Fig. 6 run, one paper-002 log)
#   SLURM_TEST_KEEP  1: keep the work directory (runs, cluster logs) after success too
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=$ROOT/.venv/bin
LOGS=${SLURM_TEST_LOGS:-phantom_c00_r01,phantom_c00_r02,phantom_c01_r01,lrde_open_r01}
HERE=$ROOT/.ci/slurm

log() { echo "==> [test-slurm] $*"; }
now() { date +%s; }

[[ $(id -u) -eq 0 ]] || { echo "make test-slurm needs root (apt-get, SLURM daemons)" >&2; exit 2; }
[[ -x $BIN/snakemake ]] || { echo "no $BIN/snakemake: run make venv-slurm" >&2; exit 2; }
"$BIN/python" -c "import snakemake_executor_plugin_slurm" 2>/dev/null \
    || { echo "the SLURM executor plugin is not in .venv: run make venv-slurm" >&2; exit 2; }

t0=$(now)
bash "$HERE/cluster.sh" install
t_install=$(($(now) - t0))

WORK=$(mktemp -d -t enclab-test-slurm.XXXXXX)
status=1
cleanup() {
    bash "$HERE/cluster.sh" stop "$WORK/cluster" || true
    if [[ $status -eq 0 && ${SLURM_TEST_KEEP:-0} != 1 ]]; then
        rm -rf "$WORK"
    else
        log "work directory kept: $WORK (runs, cluster/log/)"
    fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Two identical work directories: the configuration and the raw data (read-only, symlinked).
if [[ $LOGS == all ]]; then
    CONFIG=() IDS=$("$BIN/python" -c "import yaml; print(' '.join(e['id'] for e in yaml.safe_load(open('$ROOT/data/manifest.yaml'))['logs']))")
else
    CONFIG=(--config "only_logs=[$LOGS]") IDS=${LOGS//,/ }
fi
for run in local slurm; do
    mkdir -p "$WORK/$run"
    ln -s "$ROOT/config.yaml" "$WORK/$run/config.yaml"
    ln -s "$ROOT/data" "$WORK/$run/data"
done
export MPLBACKEND=Agg

log "local run (--cores 2) of logs: $IDS"
t0=$(now)
(cd "$WORK/local" && "$BIN/snakemake" --snakefile "$ROOT/Snakefile" --cores 2 "${CONFIG[@]}") \
    >"$WORK/local.log" 2>&1 || { tail -50 "$WORK/local.log"; log "local run failed"; exit 1; }
t_local=$(($(now) - t0))

t0=$(now)
bash "$HERE/cluster.sh" start "$WORK/cluster"
export SLURM_CONF=$WORK/cluster/etc/slurm.conf
t_cluster=$(($(now) - t0))

# The profile as a user runs it. Two command-line additions for a test on one small node: the
# first status check after 5 s instead of 40 s, and 2 logs per group job so that the two CPUs
# run two group jobs side by side.
log "SLURM run: --executor slurm --workflow-profile workflow/profiles/slurm"
t0=$(now)
(cd "$WORK/slurm" && "$BIN/snakemake" --snakefile "$ROOT/Snakefile" --executor slurm \
    --workflow-profile "$ROOT/workflow/profiles/slurm" --slurm-init-seconds-before-status-checks 5 \
    --group-components per_log=2 "${CONFIG[@]}") >"$WORK/slurm.log" 2>&1 \
    || { tail -80 "$WORK/slurm.log"; log "SLURM run failed"; exit 1; }
t_slurm=$(($(now) - t0))

# The jobs really went through SLURM: every job of this run is in the accounting database and
# COMPLETED.
sacct -X --noheader --parsable2 --format=JobID,JobName,AllocCPUS,Elapsed,State >"$WORK/sacct.txt"
log "SLURM jobs (sacct): id|name|cpus|elapsed|state"
sed 's/^/    /' "$WORK/sacct.txt"
n_jobs=$(wc -l <"$WORK/sacct.txt")
n_done=$(grep -c '|COMPLETED$' "$WORK/sacct.txt" || true)
if ((n_jobs == 0 || n_done != n_jobs)); then
    log "expected every SLURM job COMPLETED, got $n_done of $n_jobs"
    exit 1
fi

"$BIN/python" "$HERE/compare.py" "$WORK/local" "$WORK/slurm" $IDS
log "wall times: apt/check ${t_install}s, local run ${t_local}s, cluster start ${t_cluster}s, SLURM run ${t_slurm}s ($n_jobs SLURM jobs)"
status=0
log "passed"
