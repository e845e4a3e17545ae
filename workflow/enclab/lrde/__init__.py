"""Paper 002 (Zhang & Gao): the offset angle of an extreme low-resolution digital encoder
(LRDE) and the stroke and bias of the motion it reads, by Bayesian inference from the dwell
pattern, with the encoder's and the clock's own effects compared and, when one is found, in
the model.

Entry point: :func:`enclab.lrde.pipeline.analyse_lrde_log` (canonical log in; the ``lrde``
block with the estimates before and after the chosen effect, figures and report out).

Submodules (import them explicitly; this package does no heavy imports):

- :mod:`enclab.lrde.model`        offset-encoder model, stroke/bias descriptors, eqs. (4)-(20)
- :mod:`enclab.lrde.dwell`        run lengths, cycle segmentation, dwell-based baselines
- :mod:`enclab.lrde.simulate`     open-loop and closed-loop (PID, Fig. 5) simulated logs
- :mod:`enclab.lrde.effects`      hysteresis/play, frequency drift, count jump, sample-time jitter
- :mod:`enclab.lrde.compare`      held-out comparison of the candidate models
- :mod:`enclab.lrde.fit`          Bayesian inference with emcee
- :mod:`enclab.lrde.diagnostics`  autocorrelation time, split R-hat, ESS
- :mod:`enclab.lrde.plots`        figures (corner, dwell posterior predictive, Fig. 6)
- :mod:`enclab.lrde.report`       the ``lrde`` block of summary.json and a Markdown report
- :mod:`enclab.lrde.pipeline`     canonical log in, block/figures/report/cycles out
"""

__all__ = ["model", "dwell", "simulate", "effects", "compare", "fit", "diagnostics", "plots",
           "report", "pipeline"]
