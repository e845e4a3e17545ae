"""Rule requantize: truth channels -> integer counts at every re-quantization level."""
from enclab.propagation import pipeline
from enclab.runner import run


def main(smk):
    pipeline.requantize(smk.input.canonical, smk.params.requantize, smk.output.requantized)


run(snakemake, main)  # noqa: F821
