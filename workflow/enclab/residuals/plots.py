"""Figures of the residual stage: one diagnostics grid per measured channel, and the residual
before and after the selected effects.

Each function returns a :class:`matplotlib.figure.Figure` built without ``pyplot`` (nothing
global to close); the caller saves it. Residuals are shown in units of the measured channel's
step (the quantization floor is then read off directly), angles in degrees.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure

__all__ = ["diagnostics_figure", "before_after_figure", "covariates_figure"]

_DEG = 180.0 / np.pi


def _binned_panel(ax, b, scale, xlabel, title, xscale=1.0):
    ok = b["n"] > 0
    x = b["centres"][ok] * xscale
    ax.errorbar(x, b["mean"][ok] * scale, yerr=b["sem"][ok] * scale, fmt="o-", ms=3, lw=1,
                capsize=0, label="mean")
    ax.plot(x, b["std"][ok] * scale, "s", ms=2.5, color="0.55", label="std")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel(xlabel)
    ax.set_title(title, fontsize=9)


def diagnostics_figure(t, truth, diag: Mapping, step: float, *, title: str = "",
                       max_trace_points: int = 20000) -> Figure:
    """Grid of the residual diagnostics of one measured channel.

    Parameters
    ----------
    t, truth : array_like
        Time (s) and truth angle (rad).
    diag : dict
        :func:`enclab.residuals.diagnostics.diagnose` result.
    step : float
        Measured channel's step (rad); residuals are plotted in steps.
    title : str
        Figure title (log and channel).
    max_trace_points : int
        The time trace is decimated to at most this many points (stride, deterministic).

    Returns
    -------
    matplotlib.figure.Figure
        3 x 3 panels: residual vs time, error histogram vs prediction, Welch spectrum; residual
        conditioned on angle mod 2 pi, on angle mod line pitch, on count mod 4; on velocity,
        on the sign of velocity, on time.
    """
    t = np.asarray(t, dtype=float)
    truth = np.asarray(truth, dtype=float)
    scale = 1.0 / step
    cond = diag["conditioned"]
    fig = Figure(figsize=(13, 10), layout="constrained")
    axes = fig.subplots(3, 3)

    ax = axes[0, 0]
    stride = max(1, t.size // max_trace_points)
    ax.plot(t[::stride], diag["residual"][::stride] * scale, lw=0.5, label="measured - q(truth)")
    ax.plot(t[::stride], diag["error"][::stride] * scale, lw=0.3, alpha=0.5,
            label="measured - truth - c")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("[steps]")
    ax.set_title("residual and error vs time", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")

    ax = axes[0, 1]
    h = diag["histogram"]
    edges = h["edges"] * scale
    ax.stairs(h["density"] / scale, edges, label="measured", fill=True, alpha=0.5)
    ax.stairs(h["predicted"] / scale, edges, label="quantization alone", color="k")
    ax.axvline(-0.5, color="r", lw=0.6, ls=":")
    ax.axvline(0.5, color="r", lw=0.6, ls=":")
    ax.set_xlabel("measured - truth - c [steps]")
    ax.set_ylabel("density [1/step]")
    ax.set_title(f"error histogram: outside +-step/2 {100 * h['mass_outside']:.2f} % "
                 f"(model {100 * h['mass_outside_predicted']:.2f} %)", fontsize=9)
    ax.legend(fontsize=7)

    ax = axes[0, 2]
    sp = diag["spectrum"]
    ok = sp["f_hz"] > 0
    ax.loglog(sp["f_hz"][ok], np.maximum(sp["psd"][ok], 1e-300) / step**2, lw=0.8)
    floor = diag["floor"]["residual_std"]
    if floor > 0:
        ax.axhline(floor**2 / (sp["fs_hz"] / 2) / step**2, color="k", ls="--", lw=0.7,
                   label="floor if white")
        ax.legend(fontsize=7)
    ax.set_xlabel("f [Hz]")
    ax.set_ylabel("PSD [step^2/Hz]")
    ax.set_title("residual spectrum (Welch)", fontsize=9)

    _binned_panel(axes[1, 0], cond["angle_mod_2pi"], scale, "truth mod 2 pi, wrapped [deg]",
                  "residual vs angle mod 2 pi", xscale=_DEG)
    _binned_panel(axes[1, 1], cond["angle_mod_pitch"], scale, "truth mod line pitch [pitch]",
                  "residual vs angle mod line pitch")
    _binned_panel(axes[1, 2], cond["count_mod_4"], scale, "count mod 4", "residual vs count mod 4")
    _binned_panel(axes[2, 0], cond["velocity"], scale, "truth velocity [deg/s]",
                  "residual vs velocity", xscale=_DEG)
    ax = axes[2, 1]
    vs = cond["velocity_sign"]
    means = [vs["backward"]["mean"] * scale, vs["forward"]["mean"] * scale]
    stds = [vs["backward"]["std"] * scale, vs["forward"]["std"] * scale]
    ax.bar([0, 1], means, yerr=stds, color=["tab:orange", "tab:blue"], capsize=3)
    ax.set_xticks([0, 1], [f"v < 0 (n={vs['backward']['n']})", f"v > 0 (n={vs['forward']['n']})"])
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_title(f"residual by direction: difference {vs['difference'] * scale:.3g} steps",
                 fontsize=9)
    _binned_panel(axes[2, 2], cond["time"], scale, "t [s]", "residual vs time (binned)")
    for ax in axes[1:].ravel():
        ax.set_ylabel("residual [steps]")
    rm = diag["residual_moments"]
    fig.suptitle(f"{title}  step {step * 1e3:.4g} mrad, offset c = {diag['offset'] / step:.3f} steps; "
                 f"residual std {rm['std'] / step:.3g} steps (exact-model floor "
                 f"{diag['floor']['residual_std'] / step:.3g})", fontsize=10)
    return fig


def before_after_figure(t, truth, measured, before, after, step: float, *, title: str = "",
                        effects_label: str = "", max_trace_points: int = 20000) -> Figure:
    """The measured channel's residual against the exact model before and after the effects.

    Parameters
    ----------
    t, truth, measured : array_like
        Time (s), truth and measured angles (rad).
    before, after : array_like
        Model predictions of the measured channel: exact quantizer model, and with the selected
        effects (``SelectionResult.model_prediction``).
    step : float
        Measured channel's step (rad).
    effects_label : str
        The selected effects (shown in the title).

    Returns
    -------
    matplotlib.figure.Figure
        Residual vs time before and after, residual vs truth angle (loops show play or
        hysteresis), and the two residual histograms.
    """
    t = np.asarray(t, dtype=float)
    truth = np.asarray(truth, dtype=float)
    measured = np.asarray(measured, dtype=float)
    r0 = (measured - np.asarray(before, dtype=float)) / step
    r1 = (measured - np.asarray(after, dtype=float)) / step
    stride = max(1, t.size // max_trace_points)
    fig = Figure(figsize=(13, 4.2), layout="constrained")
    a0, a1, a2 = fig.subplots(1, 3)
    a0.plot(t[::stride], r0[::stride], lw=0.5, label=f"before (std {r0.std():.3g})")
    a0.plot(t[::stride], r1[::stride], lw=0.5, label=f"after (std {r1.std():.3g})")
    a0.set_xlabel("t [s]")
    a0.set_ylabel("measured - model [steps]")
    a0.legend(fontsize=7)
    a1.plot(truth[::stride] * _DEG, r0[::stride], ",", alpha=0.5, label="before")
    a1.plot(truth[::stride] * _DEG, r1[::stride], ",", alpha=0.5, label="after")
    a1.set_xlabel("truth [deg]")
    a1.set_ylabel("measured - model [steps]")
    a1.set_title("residual vs angle", fontsize=9)
    lo = min(r0.min(), r1.min()) - 0.5
    hi = max(r0.max(), r1.max()) + 0.5
    edges = np.arange(np.floor(lo) - 0.5, np.ceil(hi) + 1.0, 1.0) if hi - lo < 200 else 80
    a2.hist(r0, bins=edges, histtype="stepfilled", alpha=0.5, label="before")
    a2.hist(r1, bins=edges, histtype="step", color="k", label="after")
    a2.set_yscale("log")
    a2.set_xlabel("measured - model [steps]")
    a2.set_title("residual histogram", fontsize=9)
    a2.legend(fontsize=7)
    fig.suptitle(f"{title}  effects: {effects_label or 'none'}", fontsize=10)
    return fig


def covariates_figure(r, covariates: Mapping, ranking, step: float, *, title: str = "", top: int = 3,
                      n_bins: int = 24, max_points: int = 20000) -> Figure:
    """The residual after the effects against its top covariates.

    Parameters
    ----------
    r : array_like
        Residual after the selected effects (rad).
    covariates : dict
        ``{name: array}`` (:func:`enclab.residuals.diagnostics.covariates_of`).
    ranking : list of dict
        :func:`enclab.residuals.diagnostics.rank_covariates` result (held-out shares).
    step : float
        Measured channel's step (rad); the residual is shown in steps.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per covariate (at most ``top``): the samples, their binned mean, and the
        held-out share in the title.
    """
    from enclab.residuals.diagnostics import binned

    r = np.asarray(r, dtype=float) / step
    shown = list(ranking)[:top]
    fig = Figure(figsize=(4.2 * max(len(shown), 1), 3.8), layout="constrained")
    axs = np.atleast_1d(fig.subplots(1, max(len(shown), 1)))
    stride = max(1, r.size // max_points)
    for ax, d in zip(axs, shown):
        x = np.asarray(covariates[d["name"]], dtype=float)
        ax.plot(x[::stride], r[::stride], ",", color="0.6")
        edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
        if edges.size >= 2:
            b = binned(x, r, edges)
            ok = b["n"] > 0
            ax.plot(binned(x, x, edges)["mean"][ok], b["mean"][ok], "o-", ms=3, color="C3", label="binned mean")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel(d["name"])
        ax.set_title(f"{d['name']}: {100 * d['share']:.0f} % held out", fontsize=9)
    axs[0].set_ylabel("residual after the effects [steps]")
    if not shown:
        axs[0].text(0.5, 0.5, "no covariate", ha="center", va="center", transform=axs[0].transAxes)
    fig.suptitle(f"{title}  what the rest follows", fontsize=10)
    return fig
