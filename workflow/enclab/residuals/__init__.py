"""Residual stage: what the exact quantizer model misses on a measured channel against a
reference, which physical effect explains it, and where to look when none does.

Entry points: :func:`enclab.residuals.pipeline.analyse_channel` (one log's channel pair: the
effects selected with nothing declared, the error before and after, the verdict against the
exact-model floor) and :func:`enclab.residuals.rig.evaluate` (runs of one rig together:
shared effects fitted on training runs, scored on held-out runs).

- :mod:`enclab.residuals.effects`       the effect library (composable terms of the channel's model)
- :mod:`enclab.residuals.select`        forward selection with held-out confirmation
  (:func:`~enclab.residuals.select.select_effects`)
- :mod:`enclab.residuals.diagnostics`   residual diagnostics and what the rest follows
  (covariate ranking)
- :mod:`enclab.residuals.calibration`   the calibration map and compliance terms of a rig
- :mod:`enclab.residuals.rig`           the rig fit, its splits and held-out scores
- :mod:`enclab.residuals.rig_manifest`  the manifest's ``rig`` key
- :mod:`enclab.residuals.rig_report`    the rig's report, tables and figures
- :mod:`enclab.residuals.plots`         per-log figures
- :mod:`enclab.residuals.simulate`      simulated two-channel logs with known effects
"""
