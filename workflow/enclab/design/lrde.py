"""Low-resolution encoder design: how many cycles, or what sample rate, for a requested precision.

Zhang & Gao's encoder reads a sinusoid with a stroke of a few steps; the Bayesian fit
(:mod:`enclab.lrde.fit`) recovers the stroke ``A12`` and the bias deviation ``E_b`` from the
dwell pattern. Their posterior RMSE falls with the number of cycles in the log and with the
number of samples per motion period (the dwell ends are located to a fraction of a sample
interval, and cycles sampled at different phases interleave). A :class:`PrecisionLaw`
``rmse = k * cycles^-alpha * (samples_per_period / 100)^-beta`` (in steps) is fitted to RMSEs
measured on simulated logs (``workflow/benchmarks/design_lrde_scaling.py`` measures both the
posterior median's RMSE and the information floor of an oracle that knows frequency, phase and
jitter); inverting it gives the cycles for a requested RMSE at a given sample rate, or the
sample rate for a given number of cycles.

The law is an empirical fit over the measured range (reported with it); outside that range
it is an extrapolation, and the design says so.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["PrecisionLaw", "fit_law", "lrde_design"]

_SPP_REF = 100.0


@dataclass(frozen=True)
class PrecisionLaw:
    """``rmse = k * cycles^-alpha * (samples_per_period / 100)^-beta`` (steps).

    ``cycles_range`` and ``spp_range`` are the measured ranges the law was fitted on.
    """

    k: float
    alpha: float
    beta: float
    cycles_range: tuple[float, float] = (1.0, math.inf)
    spp_range: tuple[float, float] = (0.0, math.inf)

    def rmse(self, cycles, samples_per_period):
        cycles = np.asarray(cycles, dtype=float)
        spp = np.asarray(samples_per_period, dtype=float)
        return self.k * cycles ** -self.alpha * (spp / _SPP_REF) ** -self.beta

    def cycles_for(self, rmse: float, samples_per_period: float) -> float:
        """Cycles at which the law reaches ``rmse`` (steps) at ``samples_per_period``."""
        if not rmse > 0 or not samples_per_period > 0:
            raise ValueError(f"rmse and samples_per_period must be positive, got {rmse!r}, "
                             f"{samples_per_period!r}")
        if self.alpha <= 0:
            raise ValueError(f"the law does not improve with cycles (alpha={self.alpha:.3g})")
        base = self.k * (samples_per_period / _SPP_REF) ** -self.beta
        return float((base / rmse) ** (1.0 / self.alpha))

    def samples_per_period_for(self, rmse: float, cycles: float) -> float:
        """Samples per motion period at which the law reaches ``rmse`` (steps) in ``cycles``."""
        if not rmse > 0 or not cycles > 0:
            raise ValueError(f"rmse and cycles must be positive, got {rmse!r}, {cycles!r}")
        if self.beta <= 0:
            raise ValueError(f"the law does not improve with the sample rate (beta={self.beta:.3g})")
        base = self.k * cycles ** -self.alpha
        return float(_SPP_REF * (base / rmse) ** (1.0 / self.beta))

    def to_dict(self) -> dict:
        return {"k_steps": self.k, "alpha": self.alpha, "beta": self.beta,
                "cycles_range": list(self.cycles_range), "samples_per_period_range": list(self.spp_range)}

    @classmethod
    def from_dict(cls, spec: Mapping) -> "PrecisionLaw":
        try:
            return cls(float(spec["k_steps"]), float(spec["alpha"]), float(spec["beta"]),
                       tuple(spec.get("cycles_range", (1.0, math.inf))),
                       tuple(spec.get("samples_per_period_range", (0.0, math.inf))))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"a precision law needs k_steps, alpha and beta, got {dict(spec)!r}") from err


def fit_law(table: pd.DataFrame, column: str = "rmse_steps") -> tuple[PrecisionLaw, dict]:
    """Least-squares fit of ``log rmse = log k - alpha log cycles - beta log(spp/100)``.

    Parameters
    ----------
    table : DataFrame
        Columns ``cycles``, ``samples_per_period`` and ``column`` (RMSE in steps), one row per
        measured setting.

    Returns
    -------
    law : PrecisionLaw
    stats : dict
        ``se`` of (log k, alpha, beta) and the rms log residual.
    """
    for col in ("cycles", "samples_per_period", column):
        if col not in table.columns:
            raise ValueError(f"table lacks column {col!r}")
    data = table[["cycles", "samples_per_period", column]].dropna()
    data = data[data[column] > 0]
    if data["cycles"].nunique() < 2:
        raise ValueError("fitting the law needs settings with at least 2 different cycle counts")
    X = np.column_stack([np.ones(len(data)), -np.log(data["cycles"]),
                         -np.log(data["samples_per_period"] / _SPP_REF)])
    y = np.log(data[column].to_numpy())
    vary_spp = data["samples_per_period"].nunique() > 1
    if not vary_spp:
        X = X[:, :2]
    if len(data) < X.shape[1]:
        raise ValueError(f"fitting the law needs at least {X.shape[1]} settings, got {len(data)}")
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    dof = max(len(y) - X.shape[1], 1)
    cov = np.linalg.inv(X.T @ X) * float(resid @ resid) / dof
    se = np.sqrt(np.diag(cov)).tolist() + ([] if vary_spp else [math.nan])
    law = PrecisionLaw(float(math.exp(coef[0])), float(coef[1]), float(coef[2]) if vary_spp else 0.0,
                       (float(data["cycles"].min()), float(data["cycles"].max())),
                       (float(data["samples_per_period"].min()), float(data["samples_per_period"].max())))
    return law, {"se_log_k": se[0], "se_alpha": se[1], "se_beta": se[2],
                 "rms_log_residual": float(np.sqrt(np.mean(resid**2)))}


def lrde_design(request: Mapping, laws: Mapping[str, Mapping]) -> dict:
    """Cycles or sample rate for a requested precision of ``A12`` and/or ``E_b``.

    Parameters
    ----------
    request : mapping
        ``step`` (rad), ``f_hz`` (motion frequency), ``A12_rmse`` and/or ``E_b_rmse`` (rad),
        and ``fs_hz`` (then the cycles are designed) and/or ``cycles`` (then the sample rate).
    laws : mapping
        ``{"A12": {...}, "E_b": {...}}`` :class:`PrecisionLaw` dicts (steps), e.g. the
        posterior laws measured by the benchmark.

    Returns
    -------
    dict
        Per quantity: the requested RMSE (rad and steps), the law, and ``cycles`` (at
        ``fs_hz``; the log then lasts ``cycles / f_hz`` s) and/or ``fs_hz`` (for ``cycles``),
        each with ``extrapolated`` when outside the law's measured range.
    """
    step = float(request["step"])
    f_hz = float(request["f_hz"])
    if not (step > 0 and f_hz > 0):
        raise ValueError("design.lrde.step and f_hz must be positive")
    out = {"step": step, "f_hz": f_hz, "quantities": {}}
    for name in ("A12", "E_b"):
        key = f"{name}_rmse"
        if request.get(key) is None:
            continue
        if name not in laws:
            raise ValueError(f"design.lrde asks for {key} but no law for {name} is configured")
        law = PrecisionLaw.from_dict(laws[name])
        target = float(request[key]) / step
        entry = {"rmse": float(request[key]), "rmse_steps": target, "law": law.to_dict()}
        if request.get("fs_hz") is not None:
            spp = float(request["fs_hz"]) / f_hz
            cycles = law.cycles_for(target, spp)
            entry["at_fs_hz"] = {"fs_hz": float(request["fs_hz"]), "samples_per_period": spp,
                                 "cycles": math.ceil(cycles), "duration_s": math.ceil(cycles) / f_hz,
                                 "extrapolated": bool(not (law.cycles_range[0] <= cycles <= law.cycles_range[1])
                                                      or not (law.spp_range[0] <= spp <= law.spp_range[1]))}
        if request.get("cycles") is not None:
            cycles = float(request["cycles"])
            spp = law.samples_per_period_for(target, cycles)
            entry["at_cycles"] = {"cycles": cycles, "samples_per_period": spp, "fs_hz": spp * f_hz,
                                  "extrapolated": bool(not (law.spp_range[0] <= spp <= law.spp_range[1])
                                                       or not (law.cycles_range[0] <= cycles <= law.cycles_range[1]))}
        out["quantities"][name] = entry
    if not out["quantities"]:
        raise ValueError("design.lrde needs A12_rmse and/or E_b_rmse")
    return out
