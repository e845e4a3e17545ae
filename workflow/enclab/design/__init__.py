"""Design mode: the encoder resolution per joint and the derivative filter that meet an error
budget over a workspace, at the least cost and lag, from the exact model and the trajectory
worst-case bound; proven by simulation.

Submodules:

- :mod:`enclab.design.problem`  the specification (device, workspace, motion, budget, candidates)
- :mod:`enclab.design.model`    per-joint noise terms and workspace weights
- :mod:`enclab.design.search`   every design evaluated, Pareto front, the choice
- :mod:`enclab.design.check`    simulation of random trajectories against the budget
- :mod:`enclab.design.lrde`     cycles or sample rate for a low-resolution encoder's precision
- :mod:`enclab.design.plots`    the Pareto figure
- :mod:`enclab.design.pipeline` configuration in, ``design`` block, table and figure out
- :mod:`enclab.design.cli`      ``python -m enclab.design``
"""

__all__ = ["problem", "model", "search", "check", "lrde", "plots", "pipeline", "cli"]
