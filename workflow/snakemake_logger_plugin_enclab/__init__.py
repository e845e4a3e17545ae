"""Snakemake logger plugin ``enclab``: ``snakemake --logger enclab`` prints one line per finished
job and one per failure (``make run`` uses it). The handler is :class:`enclab.progress.ProgressHandler`;
Snakemake finds plugins by this package's name."""
from enclab.progress import ProgressHandler as LogHandler

__all__ = ["LogHandler"]
