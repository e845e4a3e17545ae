"""The benchmarks: one module per question, each run from the repository root as
``PYTHONPATH=workflow python -m benchmarks.<name> [arguments]``.

Every module's docstring opens with the question it answers and exposes ``main(argv)``;
importing one runs nothing. Shared helpers (provenance of every row, CSV merges, Wilson
intervals, the reference loop beside a timing, simulated logs several benchmarks share) live in
:mod:`benchmarks.helpers`; :mod:`benchmarks.render_benchmarks` turns the tables into
``docs/benchmarks.md``.
``docs/development.md`` lists every module with its question and the command that
regenerates its table.
"""
