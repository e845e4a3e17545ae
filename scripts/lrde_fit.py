"""Rule lrde_fit: dwell patterns and the emcee fit of stroke, bias and offset of one log."""
import zlib

from enclab.core import atomic, canonical
from enclab.lrde.pipeline import analyse_lrde_log
from enclab.reference_effects import references_by_channel
from enclab.runner import run


def main(smk):
    df, meta = canonical.read_canonical(smk.input.canonical)
    settings = dict(smk.params.settings)
    # One stream per log, reproducible from the configured seed whatever the job order.
    seed = [int(settings.pop("seed", 0)), zlib.crc32(meta["log_id"].encode())]
    references = references_by_channel(atomic.read_json(p) for p in smk.input.residuals)
    block, figures, report_md, cycles = analyse_lrde_log(df, meta, seed, settings,
                                                         references=references,
                                                         threads=smk.threads)
    block["seed"] = seed
    atomic.write_table(cycles, smk.output.cycles)
    atomic.save_figure(figures["corner"], smk.output.corner)
    atomic.save_figure(figures["dwell_ppc"], smk.output.dwell)
    atomic.save_figure(figures["bias_cycles"], smk.output.bias_cycles)
    atomic.save_figure(figures["misfit"], smk.output.misfit)
    atomic.write_text(report_md, smk.output.report)
    atomic.write_json(block, smk.output.block)


run(snakemake, main)  # noqa: F821
