"""Does a finished run reproduce paper 000's measured/PQN and measured/exact std ratios?

Paper 000 acceptance tables from a finished run: measured/PQN and measured/exact std ratios.

Reads ``results/batch/pooled.csv`` (repeat groups pooled, ratios with confidence intervals) and
prints, and writes under ``results/benchmarks/``:

- ``fig6_position.csv``: per Fig. 6 configuration and coordinate x/y/z, the pooled position
  ratios with their intervals and the number of runs;
- ``fig7_derivatives.csv``: for the Fig. 7 group (config ``figures.fig7_group``), per
  (d, n, discretization, architecture), the min/max over cutoffs and signals of both ratios,
  the worst interval ends, and how many rows miss 1 +- tol (point estimate) and how many of
  those have an interval that still reaches the band (statistically consistent with it);
- ``exact_exclusions.csv`` (appended, with ``date``, ``machine``, ``command``): per repeat group,
  how many pooled rows have a measured/exact interval that excludes 1, and the largest
  |measured/exact - 1| over all rows and over rows whose interval is narrower than +-1 %.

Usage (after ``make run``)::

    PYTHONPATH=workflow python -m benchmarks.paper000_ratios [--pooled results/batch/pooled.csv]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd
import yaml

from .helpers import provenance

def fig6_table(pooled: pd.DataFrame) -> pd.DataFrame:
    pos = pooled[(pooled["order"] == 0) & pooled["signal"].isin(["x", "y", "z"])]
    cols = ["group", "centre_deg", "signal", "n_runs", "ratio_pqn", "ratio_pqn_lo", "ratio_pqn_hi",
            "ratio_exact", "ratio_exact_lo", "ratio_exact_hi"]
    return pos[cols].sort_values(["group", "signal"]).reset_index(drop=True)


def fig7_table(pooled: pd.DataFrame, group: str, tol: float) -> pd.DataFrame:
    der = pooled[(pooled["group"] == group) & (pooled["order"] > 0)].copy()
    der["miss"] = (der["ratio_exact"] - 1).abs() > tol
    der["miss_ci"] = der["miss"] & ((der["ratio_exact_hi"] < 1 - tol) | (der["ratio_exact_lo"] > 1 + tol))
    return (der.groupby(["d", "n", "discretization", "architecture"])
            .agg(rows=("ratio_exact", "size"),
                 exact_min=("ratio_exact", "min"), exact_max=("ratio_exact", "max"),
                 exact_lo_min=("ratio_exact_lo", "min"), exact_hi_max=("ratio_exact_hi", "max"),
                 pqn_min=("ratio_pqn", "min"), pqn_max=("ratio_pqn", "max"),
                 miss_point=("miss", "sum"), miss_even_with_ci=("miss_ci", "sum"))
            .reset_index())


def exclusions(pooled: pd.DataFrame) -> pd.DataFrame:
    """Per group: rows, rows whose measured/exact interval excludes 1, the largest deviations."""
    frame = pooled.dropna(subset=["ratio_exact", "ratio_exact_lo", "ratio_exact_hi"]).copy()
    frame["excludes"] = (frame["ratio_exact_lo"] > 1) | (frame["ratio_exact_hi"] < 1)
    frame["dev"] = (frame["ratio_exact"] - 1).abs()
    frame["narrow"] = (frame["ratio_exact_hi"] - frame["ratio_exact_lo"]) < 0.02
    out = frame.groupby("group").agg(n_runs=("n_runs", "max"), rows=("dev", "size"),
                                     excluded=("excludes", "sum"), max_dev=("dev", "max"))
    out["excluded_fraction"] = out["excluded"] / out["rows"]
    out["max_dev_narrow"] = frame[frame["narrow"]].groupby("group")["dev"].max()
    return out.reset_index()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pooled", default="results/batch/pooled.csv")
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--tol", type=float, default=0.01, help="derivative tolerance (1 %%)")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    pooled = pd.read_csv(args.pooled)
    group = yaml.safe_load(Path(args.config).read_text())["figures"]["fig7_group"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    f6, f7 = fig6_table(pooled), fig7_table(pooled, group, args.tol)
    f6.to_csv(out / "fig6_position.csv", index=False)
    f7.to_csv(out / "fig7_derivatives.csv", index=False)
    excl = exclusions(pooled)
    stamp = provenance(argv)
    excl_out = pd.concat([pd.DataFrame([stamp] * len(excl)), excl], axis=1)
    path = out / "exact_exclusions.csv"
    excl_out.to_csv(path, mode="a", header=not path.exists(), index=False)
    with pd.option_context("display.width", 200, "display.max_rows", 500,
                           "display.max_columns", 30):
        print("Fig. 6 position std ratios (pooled runs, 95 % intervals)")
        print(f6.round(4).to_string(index=False))
        print(f"\nposition: measured/PQN {f6.ratio_pqn.min():.4f}..{f6.ratio_pqn.max():.4f}, "
              f"measured/exact {f6.ratio_exact.min():.4f}..{f6.ratio_exact.max():.4f}")
        print("\nRows whose 95 % interval of measured/exact excludes 1, per repeat group")
        print(excl.round(4).to_string(index=False))
        print(f"\nFig. 7 derivative std ratios, group {group}")
        print(f7.round(4).to_string(index=False))
        fc = pooled[(pooled["group"] == group) & (pooled["order"] > 0)]
        for cut in sorted(fc["fc_hz"].unique()):
            sub = fc[fc["fc_hz"] == cut]
            print(f"fc {cut:g} Hz: measured/exact {sub.ratio_exact.min():.4f}..{sub.ratio_exact.max():.4f}"
                  f" (CI {sub.ratio_exact_lo.min():.4f}..{sub.ratio_exact_hi.max():.4f}),"
                  f" measured/PQN {sub.ratio_pqn.min():.4f}..{sub.ratio_pqn.max():.4f}")


if __name__ == "__main__":
    main()
