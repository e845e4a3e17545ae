"""Residual stage: what the exact quantizer model misses, and which effect explains it.

:mod:`enclab.residuals.effects` holds the effect library (composable terms of the measured
channel's model), :mod:`enclab.residuals.select` the forward selection with held-out
confirmation (:func:`~enclab.residuals.select.select_effects`), and
:mod:`enclab.residuals.simulate` simulated two-channel logs with known effects.
"""
