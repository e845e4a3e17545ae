# Chunked mode, the default (config chunk_size = K > 0; enclab.plan.chunk_plan cuts the chunks;
# 0 = one job per stage and log). A Snakemake `script:` job starts a new Python and imports the package:
# with one job per stage and log that start-up costs more than the work of a short log. Here one
# job runs every quantization-error stage of K logs (scripts/process_chunk.py, the same
# enclab.propagation.pipeline calls as the per-stage rules), and draws the per-log figures of the logs that show them,
# staging each log's outputs; then one shell job per log hard-links them into results/<log_id>/
# or fails with that log's error line, so a bad log still fails alone, leaves no output, and the
# rest of the workflow (batch tables, `make run`'s second pass) sees the usual per-log files.
# A chunk whose logs failed completes (they fail alone) but must not look finished to the next
# run: its record beside its log (results/logs/chunks/<chunk>.failed, not an output) changes
# its params' retry token (enclab.runner.retry_token), so the next run retries it (after a
# full disk or an unreadable file was fixed) with no cleaning; `make run`'s second pass keeps it.

import enclab.runner as enclab_runner


def chunk_retry(wildcards):
    return enclab_runner.retry_token(f"results/logs/chunks/{wildcards.chunk}",
                                     keep=config.get("batch_scope", "all") == "completed")


rule process_chunk:
    input:
        chunk_raw_inputs,
    output:
        staging=directory("results/.chunks/{chunk}"),
    params:
        entries=lambda wc: [ENTRIES[i] for i in CHUNKS[wc.chunk]],
        data_root=DATA_ROOT,
        devices=config["devices"],
        requantize=config["requantize"],
        derivatives=config["derivatives"],
        moments=config["moments"],
        figures=lambda wc: [i for i in CHUNKS[wc.chunk] if i in CHUNK_FIGURE_IDS],
        code=CODE_DIGEST,
        retry=chunk_retry,
        record=lambda wc: f"results/logs/chunks/{wc.chunk}",
    threads: 1
    log:
        "results/logs/chunks/{chunk}.log",
    benchmark:
        "results/logs/chunks/{chunk}.benchmark.tsv"
    script:
        "../../scripts/process_chunk.py"


# A shell job, not a Python script or `run:` block: Snakemake starts a Python (a whole
# Snakemake, for `run:`) per such job, which is the overhead this mode removes. It only links
# files: one `ln` links the staged log as the rule's log, a second hard-links every staged
# output into results/<log_id>/ in one call (about 4 ms CPU per log). The outputs are linked
# under their final names, with no temporary name: Snakemake removes a job's outputs before it
# runs and after it fails, and marks them incomplete while it runs. The staged log is the
# log's whole log (every stage), kept as its rule log.
rule publish_log:
    input:
        staging=lambda wc: f"results/.chunks/{CHUNK_OF[wc.log_id]}",
    output:
        canonical="results/{log_id}/canonical.parquet",
        requantized="results/{log_id}/requantized.parquet",
        kinematics="results/{log_id}/kinematics.parquet",
        derivatives="results/{log_id}/derivatives.parquet",
        moments="results/{log_id}/moments.json",
        theory="results/{log_id}/theory.json",
        summary="results/{log_id}/summary.json",
    params:
        staged=lambda wc: f"results/.chunks/{CHUNK_OF[wc.log_id]}/{wc.log_id}",
        files=lambda wc, output: [f"results/.chunks/{CHUNK_OF[wc.log_id]}/{wc.log_id}/"
                                  f"{os.path.basename(f)}" for f in output],
        folder=lambda wc: f"results/{wc.log_id}",
    wildcard_constraints:
        log_id=ids_regex(CHUNKED_IDS),
    localrule: True
    log:
        "results/{log_id}/logs/quantization.log",
    benchmark:
        "results/{log_id}/benchmarks/quantization.tsv"
    shell:
        "ln -f {params.staged:q}.log {log:q}; "
        "if [ -e {params.staged:q}.failed ]; then "
        "[ -n \"${{ENCLAB_QUIET_JOBS:-}}\" ] || cat {params.staged:q}.failed >&2; exit 1; fi; "
        "ln -f {params.files:q} {params.folder:q}/"


# The figures a chunk drew (CHUNK_FIGURE_IDS); as publish_log, a failed log fails here too.
rule publish_figures:
    input:
        staging=lambda wc: f"results/.chunks/{CHUNK_OF[wc.log_id]}",
    output:
        errors="results/{log_id}/figures/errors.png",
        comparison="results/{log_id}/figures/comparison.png",
    params:
        staged=lambda wc: f"results/.chunks/{CHUNK_OF[wc.log_id]}/{wc.log_id}",
        files=lambda wc, output: [f"results/.chunks/{CHUNK_OF[wc.log_id]}/{wc.log_id}/"
                                  f"figures/{os.path.basename(f)}" for f in output],
        folder=lambda wc: f"results/{wc.log_id}/figures",
    wildcard_constraints:
        log_id=ids_regex(CHUNK_FIGURE_IDS),
    localrule: True
    log:
        "results/{log_id}/logs/publish_figures.log",
    benchmark:
        "results/{log_id}/benchmarks/publish_figures.tsv"
    shell:
        "if [ -e {params.staged:q}.failed ]; then cp {params.staged:q}.failed {log:q}; "
        "[ -n \"${{ENCLAB_QUIET_JOBS:-}}\" ] || cat {params.staged:q}.failed >&2; exit 1; fi; "
        "ln -f {params.files:q} {params.folder:q}/ 2> {log:q}"


# For a chunked log both publish_log and the per-stage rules could make its files.
ruleorder: publish_figures > log_figures
ruleorder: publish_log > ingest
ruleorder: publish_log > requantize
ruleorder: publish_log > kinematics
ruleorder: publish_log > derivatives
ruleorder: publish_log > moments
ruleorder: publish_log > theory
ruleorder: publish_log > summary
