"""Residual stage: what the exact quantizer model misses on a measured channel against a
reference, which physical effect explains it, and where to look when none does.

Entry point: :func:`enclab.residuals.pipeline.analyse_channel` (one log's channel pair: the
effects selected with nothing declared, the error before and after, the verdict against the
exact-model floor). Several runs of one rig fitted together are the rig fit, :mod:`enclab.rig`,
which builds on this package (this package does not import it).

- :mod:`enclab.residuals.effects`       the effect library (composable terms of the channel's model)
- :mod:`enclab.residuals.select`        forward selection with held-out confirmation
  (:func:`~enclab.residuals.select.select_effects`)
- :mod:`enclab.residuals.diagnostics`   residual diagnostics and what the rest follows
  (covariate ranking)
- :mod:`enclab.residuals.calibration`   the calibration map and compliance terms (the effect
  library's angle map and compliance, and the shared terms of a rig fit)
- :mod:`enclab.residuals.plots`         per-log figures
- :mod:`enclab.residuals.simulate`      simulated two-channel logs with known effects
"""
