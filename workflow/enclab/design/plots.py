"""The design figure: every feasible design by cost and lag, coloured by margin, with the Pareto
front, the chosen design and the Table II (PQN) design."""
from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

__all__ = ["pareto_figure"]


def pareto_figure(designs: pd.DataFrame, pareto: pd.DataFrame, chosen: dict | None = None,
                  table2: dict | None = None, title: str = "") -> Figure:
    """Cost vs lag vs margin of the feasible designs.

    Parameters
    ----------
    designs : DataFrame
        Feasible designs (columns ``cost``, ``lag_s``, ``margin``), e.g.
        :attr:`enclab.design.search.SearchResult.designs`.
    pareto : DataFrame
        Their Pareto front (same columns).
    chosen, table2 : dict, optional
        The chosen design and the design Table II alone would choose (``cost``, ``lag_s``),
        marked on the left panel.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
        Left: lag (ms) against cost, every feasible design coloured by its margin (budget /
        predicted - 1, capped at 1), the Pareto front as a line. Right: margin against cost
        along the Pareto front.
    """
    for name, frame in (("designs", designs), ("pareto", pareto)):
        missing = [c for c in ("cost", "lag_s", "margin") if c not in frame.columns]
        if missing:
            raise ValueError(f"{name} lacks column(s) {missing}")
    fig = Figure(figsize=(10, 4.8))
    ax, ax2 = fig.subplots(1, 2)
    if not designs.empty:
        # Thin out to at most 20000 points (deterministically) so the PNG stays small.
        shown = designs if len(designs) <= 20000 else designs.iloc[:: int(np.ceil(len(designs) / 20000))]
        points = ax.scatter(shown["cost"], 1e3 * shown["lag_s"], c=np.minimum(shown["margin"], 1.0),
                            s=6, cmap="viridis", vmin=0.0, vmax=1.0, alpha=0.6, linewidths=0)
        fig.colorbar(points, ax=ax, label="margin (budget / predicted - 1)")
    if not pareto.empty:
        ax.step(pareto["cost"], 1e3 * pareto["lag_s"], where="post", color="k", lw=1.2,
                label="Pareto front")
        ax2.plot(pareto["cost"], pareto["margin"], "o-", color="k", ms=4)
    if chosen is not None:
        ax.plot([chosen["cost"]], [1e3 * chosen["lag_s"]], marker="*", ms=14, color="tab:red",
                ls="none", label="chosen (exact model)")
    if table2 is not None:
        ax.plot([table2["cost"]], [1e3 * table2["lag_s"]], marker="X", ms=10, color="tab:orange",
                ls="none", label="PQN + Table II alone")
    ax.set_xlabel("cost")
    ax.set_ylabel("lag (ms, low-frequency group delay)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=8)
    ax2.set_xlabel("cost")
    ax2.set_ylabel("margin on the Pareto front")
    ax2.grid(True, alpha=0.3)
    ax.set_title("feasible designs")
    ax2.set_title("margin along the front")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
