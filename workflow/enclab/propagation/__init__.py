"""Quantization error: how joint-space quantization error propagates to operational space and to
the estimated velocity and acceleration, measured and predicted (after Colonnese & Okamura,
"Propagation of joint space quantization error to operational space coordinates and their
derivatives").

Entry points: the per-log stage functions of :mod:`~enclab.propagation.pipeline` (what the
workflow's scripts call), built on :mod:`~enclab.propagation.analysis`; the models in
:mod:`~enclab.propagation.theory`.

- :mod:`enclab.propagation.pipeline`    the per-log stages, file to file, and the chunked mode
- :mod:`enclab.propagation.theory`      Table II (worst case, PQN), the exact non-white model,
  the trajectory worst-case bound
- :mod:`enclab.propagation.filters`     derivative estimators of Fig. 5 and their norms
- :mod:`enclab.propagation.kinematics`  devices: forward kinematics and Jacobians
- :mod:`enclab.propagation.moments`     empirical error moments with confidence intervals
- :mod:`enclab.propagation.analysis`    per-log analysis: re-quantization, errors, predictions
- :mod:`enclab.propagation.batch`       batch tables and pooled ratios across logs
- :mod:`enclab.propagation.stream`      the moments of logs too long for memory, piece by piece
- :mod:`enclab.propagation.simulate`    simulated lab logs (Phantom Premium protocol)
- :mod:`enclab.propagation.plots`       figures (Figs. 6-7, per-log errors, ratios)
"""

__all__ = ["pipeline", "theory", "filters", "kinematics", "moments", "analysis", "batch", "stream",
           "simulate", "plots"]
