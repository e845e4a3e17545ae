"""Rule process_chunk: every quantization-error stage of several logs in one job (chunk_size).

Each log's outputs land in results/.chunks/<chunk>/<log_id>/ only if all its stages succeed
(with the per-log figures for the logs that show them); a failing log is recorded with its
error line and the others go on (rule publish_log then fails for that log alone); the
chunk's record (token, failures) makes the next run retry a failed log."""
import logging

from enclab.propagation import pipeline
from enclab.runner import record_chunk, run, run_chunk


def main(smk):
    p = smk.params
    config = {"devices": p.devices, "requantize": p.requantize, "derivatives": p.derivatives,
              "moments": p.moments}
    figures = set(p.figures)
    status = run_chunk(
        p.entries, lambda entry, folder: pipeline.quantization_log(
            entry, folder, config, p.data_root, figures=entry["id"] in figures),
        smk.output.staging, data_root=p.data_root)
    record_chunk(p.record, p.retry, status)
    failed = sorted(log_id for log_id, line in status.items() if line is not None)
    logging.getLogger("enclab.process_chunk").info(
        "%d of %d logs completed; failed: %s", len(status) - len(failed), len(status), failed)


run(snakemake, main)  # noqa: F821
