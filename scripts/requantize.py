"""Rule requantize: truth channels -> integer counts at every re-quantization level."""
from enclab import analysis, io
from enclab.runner import run


def main(smk):
    df, meta = io.read_canonical(smk.input.canonical)
    settings = dict(smk.params.requantize)
    settings.update((meta.get("analysis") or {}).get("requantize") or {})
    levels = analysis.plan_levels(meta, settings)
    meta = dict(meta, levels=levels)
    io.write_canonical(analysis.requantize(df, meta, levels), meta, smk.output.requantized)


run(snakemake, main)  # noqa: F821
