"""Extreme low-resolution digital encoder (LRDE) of Zhang & Gao.

Submodules (import them explicitly; this package does no heavy imports):

- :mod:`enclab.lrde.model`        offset-encoder model, stroke/bias descriptors, eqs. (4)-(20)
- :mod:`enclab.lrde.dwell`        run lengths, cycle segmentation, dwell-based baselines
- :mod:`enclab.lrde.simulate`     open-loop and closed-loop (PID, Fig. 5) simulated logs
- :mod:`enclab.lrde.fit`          Bayesian inference with emcee
- :mod:`enclab.lrde.diagnostics`  autocorrelation time, split R-hat, ESS
- :mod:`enclab.lrde.plots`        figures (corner, dwell posterior predictive, Fig. 6)
- :mod:`enclab.lrde.report`       the ``lrde`` block of summary.json and a Markdown report
- :mod:`enclab.lrde.pipeline`     canonical log in, block/figures/report/cycles out
"""

__all__ = ["model", "dwell", "simulate", "fit", "diagnostics", "plots", "report", "pipeline"]
