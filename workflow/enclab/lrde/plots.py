"""Figures of the extreme low-resolution encoder analysis (Zhang & Gao).

Each function returns a :class:`matplotlib.figure.Figure` built without ``pyplot`` (nothing
global to close); the caller saves it. Angles are shown in degrees (the paper's unit), the
data stay SI.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal", Figs. 2 and 6.
"""
from __future__ import annotations

import corner
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from enclab.lrde import dwell, model
from enclab.lrde import effects as lrde_effects

__all__ = ["corner_plot", "posterior_predictive_dwell", "dwell_ppc_plot", "closed_loop_plot",
           "bias_cycles_plot", "truth_bias_deviation", "misfit_plot", "loop_corner_plot"]

_DEG = 180.0 / np.pi


def corner_plot(fit, truths: dict | None = None) -> Figure:
    """Corner plot of ``A12``, ``E_b`` (deg), ``f`` (Hz), ``phase`` (rad), ``sigma`` (deg).

    Parameters
    ----------
    fit : enclab.lrde.fit.FitResult
    truths : dict, optional
        True values (SI) by parameter name, drawn as lines (simulated data).
    """
    extra = fit.param_names[5:]
    effect_axes = {name: term.display for name, term in lrde_effects.REGISTRY.items()
                   if term.display[1]}  # each term's own axis (scale, label)
    scale = np.array([_DEG, _DEG, 1.0, 1.0, _DEG]
                     + [effect_axes.get(name, (_DEG, ""))[0] for name in extra])
    labels = [r"$A_{12}$ [deg]", r"$E_b$ [deg]", r"$f$ [Hz]", r"phase [rad]",
              r"$\sigma$ [deg]"] + [effect_axes[name][1] if name in effect_axes
                                    else f"${name[0]}_{{{name[1:]}}}$ [deg]" for name in extra]
    data = fit.samples * scale
    data[:, 0] = fit.stroke * _DEG  # the reported stroke (peak to peak, also with harmonics)
    truth_values = None
    if truths is not None:
        truth_values = [truths[name] * s if truths.get(name) is not None else None
                        for name, s in zip(fit.param_names, scale)]
    fig = Figure(figsize=(8, 8))
    corner.corner(data, labels=labels, quantiles=[0.05, 0.5, 0.95], truths=truth_values,
                  fig=fig, show_titles=True, title_fmt=".4g")
    return fig


def loop_corner_plot(fit) -> Figure:
    """Corner plot of a loop fit (:mod:`enclab.lrde.loop`): ``A12``, ``E_b``, ``sigma``
    (deg) and the plant's discrete pole ``p``."""
    names = list(fit.loop_names)
    data = np.column_stack((fit.stroke * _DEG, fit.samples[:, 1] * _DEG,
                            fit.samples[:, 4] * _DEG, fit.loop_samples[:, names.index("p")]))
    fig = Figure(figsize=(7, 7))
    corner.corner(data, labels=[r"$A_{12}$ [deg]", r"$E_b$ [deg]", r"$\sigma$ [deg]",
                                r"pole $p$"], quantiles=[0.05, 0.5, 0.95], fig=fig,
                  show_titles=True, title_fmt=".4g")
    return fig


def posterior_predictive_dwell(fit, t, seed, n_draws=40) -> pd.DataFrame:
    """Per-cycle dwell half-widths of counts simulated from posterior draws.

    Each draw re-reads its sinusoid (with its own ``sigma`` of position noise) at the
    observed times and runs :func:`enclab.lrde.dwell.cycle_table` on it.

    Returns
    -------
    pandas.DataFrame
        ``draw, cycle, w1, w2, steps_pp``.
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, (int, np.integer)) or n_draws < 1:
        raise ValueError(f"n_draws must be a positive integer, got {n_draws!r}")
    rng = np.random.default_rng(seed)
    t = np.asarray(t, dtype=float)
    idx = rng.choice(fit.samples.shape[0], size=n_draws, replace=False)
    frames = []
    for d, i in enumerate(idx):
        row = fit.samples[i]
        E_b, f_hz, sigma = row[1], row[2], row[4]
        a_eq = (fit.centre_count + 0.5) * fit.step + E_b
        if fit.effects:
            counts = fit.simulate_counts(t, row, rng)
        else:
            theta = fit.motion(t, row) + rng.normal(0.0, sigma, t.size)
            counts = model.encoder_counts(theta, fit.step, a_eq)
        table = dwell.cycle_table(counts, t, fit.step, f_hz=float(f_hz))
        frames.append(pd.DataFrame({"draw": d, "cycle": table["cycle"], "w1": table["w1"],
                                    "w2": table["w2"], "steps_pp": table["steps_pp"]}))
    return pd.concat(frames, ignore_index=True)


def dwell_ppc_plot(cycles: pd.DataFrame, predictive: pd.DataFrame) -> Figure:
    """Observed dwell half-widths per cycle against the posterior predictive distribution.

    Left: ``w1`` and ``w2`` (ms) per cycle, observed as markers, predictive 5-95 % band.
    Right: histograms of the observed and predicted ``w1 - w2`` (the bias signal of
    Proposition 2: a longer top dwell means ``E_b > 0``).
    """
    for name, frame, cols in (("cycles", cycles, ("cycle", "w1", "w2")),
                              ("predictive", predictive, ("cycle", "w1", "w2"))):
        missing = set(cols) - set(frame.columns)
        if missing:
            raise ValueError(f"{name} lacks columns {sorted(missing)}")
    fig = Figure(figsize=(10, 4), layout="constrained")
    ax_w, ax_d = fig.subplots(1, 2)
    band = predictive.groupby("cycle")[["w1", "w2"]].quantile([0.05, 0.95]).unstack()
    for col, colour, label in (("w1", "C0", "top dwell $w_1$"), ("w2", "C1",
                                                                 "bottom dwell $w_2$")):
        ax_w.fill_between(band.index, 1e3 * band[(col, 0.05)], 1e3 * band[(col, 0.95)],
                          color=colour, alpha=0.25, step="mid",
                          label=f"{label}, predictive 90 %")
        ax_w.plot(cycles["cycle"], 1e3 * cycles[col], "o", color=colour, ms=4,
                  label=f"{label}, observed")
    ax_w.set_xlabel("cycle")
    ax_w.set_ylabel("dwell half-width [ms]")
    ax_w.legend(fontsize=7)
    diff_obs = 1e3 * (cycles["w1"] - cycles["w2"]).to_numpy()
    diff_pred = 1e3 * (predictive["w1"] - predictive["w2"]).to_numpy()
    finite = np.concatenate((diff_obs, diff_pred))
    finite = finite[np.isfinite(finite)]
    bins = np.linspace(finite.min(), finite.max(), 30) if finite.size else 10
    ax_d.hist(diff_pred[np.isfinite(diff_pred)], bins=bins, density=True, alpha=0.5,
              color="C2", label="posterior predictive")
    ax_d.hist(diff_obs[np.isfinite(diff_obs)], bins=bins, density=True, histtype="step",
              color="k", label="observed")
    ax_d.set_xlabel(r"$w_1 - w_2$ [ms]")
    ax_d.set_ylabel("density")
    ax_d.legend(fontsize=7)
    return fig


def closed_loop_plot(df: pd.DataFrame, params: dict) -> Figure:
    """Fig. 6 equivalent: per-cycle bias relative to the ideal bias, with Prop. 1's band.

    Parameters
    ----------
    df, params
        Output of :func:`enclab.lrde.simulate.closed_loop_pid_log` (needs ``t``, ``theta``,
        ``counts``; ``step``, ``ideal_bias``, ``f_hz``).
    """
    missing = {"t", "theta", "counts"} - set(df.columns)
    if missing:
        raise ValueError(f"df lacks columns {sorted(missing)}")
    per_cycle = dwell.cycle_bias(df["t"].to_numpy(), df["theta"].to_numpy(), params["f_hz"])
    step = params["step"]
    half_eps = 0.5 * np.asarray(model.epsilon(per_cycle["A12"].to_numpy(), step))
    dev = per_cycle["bias"].to_numpy() - params["ideal_bias"]
    fig = Figure(figsize=(8, 6), layout="constrained")
    ax_b, ax_r = fig.subplots(2, 1, sharex=True)
    ax_b.plot(per_cycle["t_mid"], _DEG * dev, "o-", ms=3,
              label=r"$A_{12-b} - \overline{A_{12-b}}$ (per cycle)")
    ax_b.plot(per_cycle["t_mid"], _DEG * half_eps, "k--", label=r"$\pm\varepsilon/2$")
    ax_b.plot(per_cycle["t_mid"], -_DEG * half_eps, "k--")
    ax_b.axhline(0.0, color="0.5", lw=0.8)
    ax_b.set_ylabel("bias deviation [deg]")
    ax_b.legend(fontsize=8)
    ax_r.plot(df["t"], _DEG * df["theta"], lw=0.8, label=r"true $\theta$")
    ax_r.step(df["t"], _DEG * step * df["counts"], where="post", lw=0.8,
              label=r"reading $\theta_{enc}$")
    ax_r.set_xlabel("time [s]")
    ax_r.set_ylabel("angle [deg]")
    ax_r.legend(fontsize=8)
    return fig


def truth_bias_deviation(t, truth, f_hz, step, offset_a, centre_count) -> pd.DataFrame:
    """Per-period bias deviation ``E_b`` of the true angle, in the readings' frame.

    ``E_b = bias + a - (c + 1/2) step`` (eq. 14 relative to the centre count ``c``: zero when
    the motion is centred on the middle of reading ``c``), with ``bias`` and ``A12`` per period
    from :func:`enclab.lrde.dwell.cycle_bias`. Columns ``t_mid, A12, bias, E_b``.
    """
    per_period = dwell.cycle_bias(t, truth, f_hz)
    per_period["E_b"] = per_period["bias"] + offset_a - (centre_count + 0.5) * step
    return per_period


def bias_cycles_plot(cycles: pd.DataFrame, step: float, truth_periods: pd.DataFrame | None = None,
                     fitted: dict | None = None) -> Figure:
    """Paper 002 Fig. 6 from a log: per-cycle bias deviation in Proposition 1's band.

    Top: ``E_b`` of every symmetric cycle from its dwell half-widths (eq. 4/14; readings only)
    with the band ``+- epsilon/2`` of that cycle's stroke, and, when given, the true per-period
    ``E_b`` (:func:`truth_bias_deviation`). Bottom: the readings' peak-to-peak step count per
    cycle, which stays ``2n`` while the bias stays inside the band.

    Parameters
    ----------
    cycles : pandas.DataFrame
        :func:`enclab.lrde.dwell.cycle_table`.
    step : float
        Encoder step (rad).
    truth_periods : pandas.DataFrame, optional
        Columns ``t_mid`` and ``E_b`` (rad).
    fitted : dict, optional
        The fitted motion's ``E_b`` (``{median, q05, q95}``, rad, about the mean of its
        turning points) and its model ``label``: drawn as its median and 90 % band over the
        log (a periodic model has one bias for the whole log).
    """
    missing = {"t_start", "t_end", "symmetric", "A12_dwell", "E_b_dwell", "steps_pp"} - set(cycles)
    if missing:
        raise ValueError(f"cycles lacks columns {sorted(missing)}")
    t_mid = 0.5 * (cycles["t_start"] + cycles["t_end"]).to_numpy()
    sym = cycles["symmetric"].to_numpy(dtype=bool)
    fig = Figure(figsize=(8, 6), layout="constrained")
    ax_b, ax_n = fig.subplots(2, 1, sharex=True)
    if sym.any():
        half_eps = 0.5 * np.asarray(model.epsilon(cycles["A12_dwell"].to_numpy()[sym], step))
        ax_b.plot(t_mid[sym], _DEG * cycles["E_b_dwell"].to_numpy()[sym], "o", ms=3,
                  label=r"$E_b$ from the dwell half-widths (readings only)")
        ax_b.plot(t_mid[sym], _DEG * half_eps, "k--", lw=0.8,
                  label=r"$\pm\varepsilon/2$ (Proposition 1)")
        ax_b.plot(t_mid[sym], -_DEG * half_eps, "k--", lw=0.8)
    else:
        ax_b.text(0.5, 0.5, "no symmetric 2n-step cycle: eq. (4) does not apply",
                  transform=ax_b.transAxes, ha="center", va="center")
    if fitted is not None:
        span = (float(cycles["t_start"].min()), float(cycles["t_end"].max()))
        e_b = fitted["E_b"]
        ax_b.fill_between(span, _DEG * e_b["q05"], _DEG * e_b["q95"], color="C2", alpha=0.3,
                          lw=0)
        ax_b.plot(span, [_DEG * e_b["median"]] * 2, "-", color="C2", lw=1.2,
                  label=rf"$E_b$ of the fitted motion ({fitted['label']}, 90 %)")
    if truth_periods is not None:
        ax_b.plot(truth_periods["t_mid"], _DEG * truth_periods["E_b"], "-", lw=1.0,
                  color="C3", label=r"$E_b$ of the true angle (truth channel)")
    ax_b.axhline(0.0, color="0.5", lw=0.8)
    ax_b.set_ylabel("bias deviation $E_b$ [deg]")
    ax_b.legend(fontsize=8)
    ax_n.plot(t_mid, cycles["steps_pp"].to_numpy(), "o-", ms=3)
    ax_n.set_ylabel("readings peak to peak [steps]")
    ax_n.set_xlabel("time [s]")
    ax_n.yaxis.get_major_locator().set_params(integer=True)
    return fig


def misfit_plot(detail: dict | None) -> Figure:
    """The localized check of the chosen model (:func:`enclab.lrde.compare.misfit_trace`).

    Top: the readings' log-probability against what the fit expects, as ``z`` per tenth of
    the log (left) and per part of the stroke and count left or held (right), with the
    threshold ``local_z`` below which the estimates are flagged. Bottom: each dwell's end as
    its centred mid-rank under the fit (above zero: it ended later than the fit's median),
    one line per count and entry side. Noise scatters these around zero; a drift draws them
    out into slow curves, a shape the fit lacks holds a line off zero. The title gives the
    successive-dwell ``z``. ``detail`` None (no comparison ran) draws a note instead.
    """
    fig = Figure(figsize=(10, 6.5), layout="constrained")
    if not detail:
        ax = fig.subplots()
        ax.axis("off")
        ax.text(0.5, 0.5, "no model comparison ran: no localized check",
                ha="center", va="center")
        return fig
    grid = fig.add_gridspec(2, 2, width_ratios=(1.4, 1))
    ax_time, ax_parts = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1])
    ax_dwell = fig.add_subplot(grid[1, :])
    local_z = detail["local_z"]
    bins = detail["bins"]
    for ax in (ax_time, ax_parts):
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.axhline(local_z, color="C3", ls="--", lw=0.8)
    time = bins.get("time in the log")
    if time is not None:
        z = np.asarray(time["z"], dtype=float)
        ax_time.bar(np.arange(z.size), np.nan_to_num(z), color=np.where(z < local_z, "C3", "C0"))
        ax_time.set_xticks(np.arange(z.size), time["label"], fontsize=7)
        ax_time.set_xlabel("tenth of the log (centre, s)")
    ax_time.set_ylabel("z (readings vs fit)")
    ax_time.set_title(f"per tenth of the log; flagged below {local_z:g}", fontsize=9)
    labels, values = [], []
    for name, prefix in (("position and direction of the motion", ""),
                         ("count before the sample", "count ")):
        part = bins.get(name)
        if part is not None:
            labels += [prefix + str(label) for label in part["label"]]
            values += list(np.asarray(part["z"], dtype=float))
    values = np.array(values)
    ax_parts.bar(np.arange(values.size), np.nan_to_num(values),
                 color=np.where(values < local_z, "C3", "C0"))
    ax_parts.set_xticks(np.arange(values.size), labels, rotation=60, ha="right", fontsize=7)
    ax_parts.set_title("per part of the stroke and count left or held", fontsize=9)
    dwells = detail["dwells"]
    t_d, s, key = (np.asarray(dwells[k]) for k in ("t", "s", "key"))
    for k in np.unique(key):
        mine = key == k
        if mine.sum() >= 2:
            ax_dwell.plot(t_d[mine], s[mine], ".-", ms=3, lw=0.7, label=dwells["kind"][int(k)])
    ax_dwell.axhline(0.0, color="0.5", lw=0.8)
    ax_dwell.set_ylim(-0.55, 0.55)
    ax_dwell.set_xlabel("dwell start [s]")
    ax_dwell.set_ylabel("dwell end: mid-rank - 1/2")
    lag = detail.get("lag_z")
    ax_dwell.set_title("dwells' ends under the fit" + (
        f"; successive dwells alike: z = {lag:.1f} (flagged above {-local_z:g})"
        if lag is not None else ""), fontsize=9)
    if len(np.unique(key)) <= 12:
        ax_dwell.legend(fontsize=7, ncol=6, loc="upper center", bbox_to_anchor=(0.5, -0.2))
    return fig
