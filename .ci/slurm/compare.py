"""Compare the results of two workflow runs: exit 0 only if they hold the same files and every
byte-compared file (JSON, CSV, Parquet, Markdown; tests/workspace.py) is identical.

    python .ci/slurm/compare.py LOCAL_WORKDIR SLURM_WORKDIR LOG_ID...

The listed logs must each have a summary.json, so an empty or partial run cannot pass.
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from workspace import result_digests  # noqa: E402


def main(local: Path, slurm: Path, log_ids: list[str]) -> int:
    ref, got = result_digests(local), result_digests(slurm)
    problems = []
    for name, run in (("local", ref), ("slurm", got)):
        missing = [i for i in log_ids if f"{i}/summary.json" not in run]
        if missing:
            problems.append(f"{name} run: no summary.json for {missing}")
    only_ref, only_got = sorted(set(ref) - set(got)), sorted(set(got) - set(ref))
    if only_ref:
        problems.append(f"only in the local run: {only_ref}")
    if only_got:
        problems.append(f"only in the SLURM run: {only_got}")
    differ = sorted(k for k in set(ref) & set(got) if ref[k] != got[k])
    if differ:
        problems.append(f"different bytes: {differ}")
    n_bytes = sum(v != "exists" for v in ref.values())
    if problems:
        print("FAIL: SLURM results differ from the local run:\n  " + "\n  ".join(problems))
        return 1
    print(f"OK: {len(ref)} result files in both runs, {n_bytes} byte-identical "
          f"(JSON/CSV/Parquet/Markdown), {len(ref) - n_bytes} images present in both")
    return 0


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3:]))
