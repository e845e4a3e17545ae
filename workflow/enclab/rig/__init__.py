"""Rig fit: several runs of one rig (one machine under different conditions) fitted together,
the effects they share proven on held-out runs.

Entry point: :func:`enclab.rig.pipeline.report_rig` (everything rule ``rig`` writes for one
measured channel), built on :func:`enclab.rig.fit.evaluate`. The rig fit builds on the residual
effects analysis (the play operator, motion sign and the calibration and compliance bases of
:mod:`enclab.residuals`); the residual analysis does not import it.

- :mod:`enclab.rig.fit`       the rig model, its fit, splits and held-out scores
- :mod:`enclab.rig.pipeline`  a run from its canonical log, the rule's model, the whole report
- :mod:`enclab.rig.manifest`  the manifest's ``rig`` key
- :mod:`enclab.rig.report`    the rig's report, tables and figures
"""

__all__ = ["fit", "pipeline", "manifest", "report"]
