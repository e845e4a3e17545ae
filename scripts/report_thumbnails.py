"""Rule report_thumbnails: a small copy of every figure for the HTML report (one folder per
kind of figure; the full-size figures stay where their rules wrote them)."""
import os
from collections import defaultdict

from enclab.core import atomic
from enclab.runner import run


def main(smk):
    by_folder = defaultdict(list)
    for source, thumb in smk.params.pairs:
        folder = thumb.split("/")[3]  # results/report/thumbs/<kind>/...
        by_folder[os.path.join("results/report/thumbs", folder)].append((source, thumb))
    for folder, pairs in by_folder.items():
        with atomic.atomic_folder(folder) as tmp:
            for source, thumb in pairs:
                atomic.save_thumbnail(source, os.path.join(tmp, os.path.relpath(thumb, folder)),
                                      max_width=smk.params.width)


run(snakemake, main)  # noqa: F821
