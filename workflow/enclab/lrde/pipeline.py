"""One canonical log in, the ``lrde`` block, figures, report and cycle table out.

Channel selection (canonical log contract, ``docs/architecture.md``):

- measured coarse channel: ``settings["channel"]`` if given, else the first channel with
  role ``"measured"`` and storage ``"counts"``;
- truth channel: the first channel with role ``"truth"`` (same joint as the measured one when
  several); its angle is ``counts * step`` (counts storage) or the float column (rad);
- no measured channel but ``settings["requantize"] = {"step": s, "offset_frac": f}``: the
  truth is re-quantized with :func:`enclab.core.quantize.quantize` (``floor(theta/s + f)``) and
  becomes the measured channel.

With a truth channel (and ``settings["use_truth"]``, default True) the fit reports the offset
``a`` and the bias ``b`` in the truth channel's frame; with ``settings["rest_position"]`` (rad)
it uses that known motion centre; otherwise both are None with the reason.

Settings keys (all optional): ``channel``, ``requantize``, ``use_truth``, ``rest_position``,
``f_hz``, ``n_ensembles`` (4), ``n_walkers`` (16), ``n_steps`` (250), ``max_steps`` (1000:
the chains go on until they converge, up to this many steps), ``n_burn`` (100),
``ppc_draws`` (40), ``sigma_range_steps`` (prior range of the jitter in steps) and
``sigma_prior`` (``"uniform"`` or ``"log-uniform"``), see
:func:`enclab.lrde.fit.fit_sinusoid`; ``motion_models`` (candidate motion models compared
on held-out cycles, :func:`enclab.lrde.motion.motion_model`: lists of harmonic orders or
``"fourier<K>"``, default :data:`DEFAULT_MOTION_MODELS`; ``[]`` turns the comparison off) and
``effects`` (encoder and clock effects compared with them, default
all of :data:`enclab.lrde.effects.EFFECTS`), ``effect_pairs`` (also try the winner plus each
other passing term, default True), ``trust_z`` (threshold of the predictive check, default -4),
``local_z`` (threshold of the localized check, default -5),
see :func:`enclab.lrde.compare.compare_effect_models`; ``loop_models`` (loop structures
offered when the log declares a channel with role ``"command"`` on the measured joint, default
all of :data:`enclab.lrde.loop.STRUCTURES`; ``[]`` offers none), see
:func:`enclab.lrde.loop.compare_loop_models`; the one its rule chooses (else the one with
the best held-out score) is also offered with each term of ``effects`` a loop structure can
carry (:data:`enclab.lrde.loop.LOOP_EFFECTS`: a dead band, a missed count). When a loop
structure beats the periodic pick on the held-out cycles, its posterior
(:func:`enclab.lrde.loop.fit_loop`) gives the reported estimates and ``after``; the periodic
comparison's ``model`` entry moves to ``model.periodic`` and the loop's scores are under
``model.loop``.

The paper's sinusoid is fitted first (``before``); when the comparison chooses a model with
an added term, that model is fitted the same way and its posterior gives the reported
``A12``, ``E_b``, ``a_eq``, ``offset_a``, ``bias_b`` (``after``). When the comparison names
models it cannot tell from its pick (``model.indistinguishable``), or, beside a kept sinusoid,
models it does not rule out (``model.not_ruled_out``), each of them is fitted too and the
reported estimates pool all their posteriors with equal weights (``averaged``,
:func:`enclab.lrde.fit.pool_fits`; ``after`` stays the pick's own). A chosen loop structure
is pooled so with the loop comparison's ``alternatives`` (dead-band structures it cannot
rule out, :func:`enclab.lrde.loop.compare_loop_models`). ``trust`` says per
quantity whether it can be relied on and why not. With a truth channel, what the residual
stage found on the coarse channel (``references``) joins the final model and is set against
its terms (``model.reference``).
"""
from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from enclab.core import parallel
from enclab.core.canonical import Channel
from enclab.lrde import compare, dwell, fit, plots, report
from enclab.lrde import effects as lrde_effects
from enclab.lrde import loop as lrde_loop
from enclab.lrde import motion as lrde_motion

__all__ = ["select_channels", "analyse_lrde_log"]

_log = logging.getLogger(__name__)

#: Candidate motion models of the held-out comparison when ``motion_models`` is not given:
#: the sinusoid and a 2nd or a 3rd harmonic. The workflow's configuration adds Fourier series
#: of free shape (``fourier4``, ``fourier6``, :mod:`enclab.lrde.motion`) for motions set by a
#: control loop; each candidate costs the stage two point fits or more.
DEFAULT_MOTION_MODELS = ([], [2], [3])

_KNOWN_SETTINGS = {"channel", "requantize", "use_truth", "rest_position", "f_hz", "n_ensembles",
                   "n_walkers", "n_steps", "max_steps", "n_burn", "ppc_draws", "sigma_range_steps",
                   "sigma_prior", "motion_models", "effects", "effect_pairs", "trust_z",
                   "local_z", "loop_models"}


def _sampler_settings(settings: dict) -> dict:
    return {"n_ensembles": int(settings.get("n_ensembles", 4)),
            "n_walkers": int(settings.get("n_walkers", 16)),
            "n_steps": int(settings.get("n_steps", 250)),
            "max_steps": int(settings.get("max_steps", 1000)),
            "n_burn": int(settings.get("n_burn", 100)),
            "sigma_range": settings.get("sigma_range_steps"),
            "sigma_prior": settings.get("sigma_prior", "uniform")}


def _compare_effects(t, counts, step, seed, settings, threads=1) -> tuple:
    """The effect comparison's block and the comparison itself (None when not run)."""
    harmonics = [lrde_motion.motion_model(c).harmonics
                 for c in settings.get("motion_models", DEFAULT_MOTION_MODELS)]
    names = lrde_effects.check_effects(settings.get("effects", lrde_effects.EFFECTS))
    candidates = [((), ())] + [(h, ()) for h in harmonics if h] + [((), (e,)) for e in names]
    if len(candidates) < 2:
        return report.effect_model_block(None, reason="no candidate besides the sinusoid "
                                                      "(motion_models and effects empty)"), None
    try:
        comparison = compare.compare_effect_models(
            t, counts, step, seed, candidates=candidates, f_hz=settings.get("f_hz"),
            pairs=bool(settings.get("effect_pairs", True)),
            trust_z=float(settings.get("trust_z", compare.DEFAULT_TRUST_Z)),
            local_z=float(settings.get("local_z", compare.DEFAULT_LOCAL_Z)),
            sigma_range=settings.get("sigma_range_steps"),
            sigma_prior=settings.get("sigma_prior", "uniform"), threads=threads)
    except ValueError as err:
        _log.warning("effects not compared: %s", err)
        return report.effect_model_block(None, reason=str(err)), None
    return None, comparison


def _fit(t, counts, step, seed, kwargs):
    return fit.fit_sinusoid(t, counts, step, seed, **kwargs)


def _run_fits(t, counts, step, jobs, threads, beside=()):
    """The emcee fits of ``jobs`` (``(seed, kwargs)`` each), in order, ``threads`` at a time,
    followed by the results of the ``beside`` calls (``(fn, args)``) run in the same pool."""
    return parallel.call_forked([(_fit, (t, counts, step, *job)) for job in jobs]
                                + list(beside), threads)


def _alternative_kwargs(t, counts, step, comparison, added, common, settings):
    """Sampler arguments of each model the comparison could not tell from its pick or, beside
    a kept sinusoid, did not rule out (with the truth channel's added effects, like the
    pick)."""
    out = []
    for _, harmonics, own, point in compare.alternative_terms(comparison) if comparison else ():
        effects = own + tuple(e for e in added if e not in own)
        if effects != own:
            point = fit.map_fit(t, counts, step, f_hz=settings.get("f_hz"), harmonics=harmonics,
                                effects=effects, start=point["x"],
                                sigma_range=settings.get("sigma_range_steps"),
                                sigma_prior=settings.get("sigma_prior", "uniform"))
        out.append({"harmonics": harmonics, "effects": effects, "start": point["x"], **common})
    return out


def _command_channel(meta: dict, info: dict) -> dict | None:
    channels = meta.get("channels") or []
    measured = [ch for ch in channels if ch.get("name") == info.get("measured")]
    joint = measured[0].get("joint") if measured else None
    commands = [ch for ch in channels if ch.get("role") == "command"
                and (joint is None or ch.get("joint") == joint)]
    return commands[0] if commands else None


def select_command(df: pd.DataFrame, meta: dict, info: dict):
    """The commanded or reference angle (rad) of the measured channel's joint: the first
    channel with role ``"command"`` on that joint (on any joint when the measured channel has
    none), or None when the log declares none."""
    channel = _command_channel(meta, info)
    return Channel.of(channel, df).values if channel is not None else None


def loop_command(df: pd.DataFrame, meta: dict, info: dict, source: str = "the log"):
    """``(command, why_not)``: the command (:func:`select_command`) when it can drive a loop
    structure, else ``(None, why)``: a command that does not hold two whole cycles (a held
    set point, around which a quantized loop may still cycle) leaves the periodic models to
    describe the motion. A command with a sample that is not finite is bad input: a
    ValueError naming ``source`` (the file), the column and the sample."""
    channel = _command_channel(meta, info)
    if channel is None:
        return None, None
    command, name = Channel.of(channel, df).values, channel["name"]
    bad = np.flatnonzero(~np.isfinite(command))
    if bad.size:
        raise ValueError(f"{source}: column {name!r}, row {bad[0]}: the command is not "
                         f"finite ({command[bad[0]]})")
    try:
        lrde_loop.reference_cycles(command)
    except ValueError as err:
        return None, (f"the command channel {name!r} does not drive a loop structure ({err}); "
                      "the periodic models describe the motion")
    return command, None


def _loop_with_reference(chosen: str, added) -> tuple[str, list]:
    """The loop structure to fit: ``chosen`` with the encoder terms of ``added`` (the truth
    channel's findings) it can take, one term per structure; ``(label, terms added)``."""
    s = lrde_loop.loop_structure(chosen)
    taken = []
    for term in added:
        if term in lrde_loop.LOOP_EFFECTS and not s.effects:
            s = s.with_effect(term)
            taken.append(term)
    return s.label, taken


def _loop_model_block(model_block: dict, loop_cmp: dict, loop_fit, label=None,
                      added=()) -> dict:
    """The ``model`` entry when a loop structure replaces the periodic pick: the loop's
    label, comparison, check and encoder terms (those of the fitted ``label``: the choice
    with the truth channel's ``added`` terms, as for a periodic pick); the periodic
    comparison's entry under ``periodic``."""
    label = label or loop_cmp["chosen"]
    effects = list(lrde_loop.loop_structure(label).effects)
    params = dict(loop_fit.loop_params or {})
    out = {"chosen": loop_cmp["chosen"], "harmonics": [], "effects": effects,
           "signature": {e: lrde_effects.effect_signature(e) for e in effects},
           "indistinguishable": [], "not_ruled_out": [],
           "delta_bic": next(m["delta_bic"] for m in loop_cmp["models"]
                             if m["label"] == loop_cmp["chosen"]),
           "models": model_block.get("models", []), "loop": loop_cmp["models"],
           "check": dict(loop_cmp["check"]), "rule": loop_cmp["rule"],
           "n_cycles": model_block.get("n_cycles"),
           "params": params,
           "note": (f"the angle is the logged tracking error through the {label} "
                    "filter (enclab.lrde.loop); the periodic models' pick was "
                    f"{model_block.get('chosen')}"),
           "periodic": {k: v for k, v in model_block.items() if k != "models"}}
    if added:
        out["note"] += (f"; the held-out comparison chose {loop_cmp['chosen']}, and "
                        f"{', '.join(added)} joined it from the truth channel")
    sigma = (loop_fit.summary or {}).get("sigma") or {}
    if sigma.get("q05", np.inf) < 1.5 * lrde_loop.JITTER_FLOOR_STEPS * loop_fit.step:
        out["note"] += (f"; the jitter lies at its floor of {lrde_loop.JITTER_FLOOR_STEPS:g} "
                        "step (readings with little or no noise): the intervals are those of "
                        "the readings' edges softened by that much")
    return out


def select_channels(df: pd.DataFrame, meta: dict, settings: dict):
    """Pick the coarse counts, their step and the truth angle of a canonical log.

    Returns
    -------
    counts : numpy.ndarray of int64
    step : float
    truth : numpy.ndarray or None
        True angle in rad, or None.
    info : dict
        ``measured`` and ``truth`` channel names, ``requantized`` (bool) and ``truth_step``
        (the truth channel's step in rad when it is stored as counts, else None).
    """
    channels = meta.get("channels")
    if not channels:
        raise ValueError("meta['channels'] is missing or empty")
    for ch in channels:
        if ch.get("name") not in df.columns:
            raise ValueError(f"channel {ch.get('name')!r} of meta is not a column of df")
    wanted = settings.get("channel")
    if wanted is not None:
        measured = [ch for ch in channels if ch["name"] == wanted]
        if not measured:
            raise ValueError(f"settings['channel'] = {wanted!r} is not a channel of the log")
    else:
        measured = [ch for ch in channels
                    if ch.get("role") == "measured" and ch.get("storage") == "counts"]
    measured = measured[0] if measured else None
    truths = [ch for ch in channels if ch.get("role") == "truth"]
    if measured is not None and truths:
        same_joint = [ch for ch in truths if ch.get("joint") == measured.get("joint")]
        truths = same_joint or truths
    truth_ch = truths[0] if truths else None
    truth_channel = Channel.of(truth_ch, df) if truth_ch is not None else None
    truth = truth_channel.values if truth_channel is not None else None
    truth_step = truth_channel.step if truth_channel is not None and truth_channel.step else None
    if measured is not None:
        if measured.get("storage") != "counts" or not measured.get("step"):
            raise ValueError(f"measured channel {measured['name']!r} must be stored as counts "
                             f"with a step, got storage={measured.get('storage')!r}")
        coarse = Channel.of(measured, df)
        return coarse.counts.astype(np.int64), coarse.step, truth, {
            "measured": measured["name"], "truth": truth_ch and truth_ch["name"],
            "requantized": False, "truth_step": truth_step}
    req = settings.get("requantize")
    if truth is None or not req:
        raise ValueError("the log has no measured counts channel; give settings['requantize'] "
                         "= {'step': ..., 'offset_frac': ...} and a truth channel")
    from enclab.core.quantize import quantize

    if "step" not in req:
        raise ValueError(f"settings['requantize'] needs 'step', got {req!r}")
    step = float(req["step"])
    counts = quantize(truth, step, float(req.get("offset_frac", 0.5)))
    return counts, step, truth, {"measured": None, "truth": truth_ch["name"],
                                 "requantized": True, "truth_step": truth_step}


#: Largest change of the coarse count between two samples that the dwell-pattern fit accepts:
#: one step of motion plus a missed or extra count (an analog sensor's levels toggle by 2).
MAX_COUNT_CHANGE = 2


def check_count_changes(t, counts, where: str) -> None:
    """Raise a one-line error at the first sample whose count differs from the previous one by
    more than :data:`MAX_COUNT_CHANGE`.

    The dwell pattern assumes that the motion moves less than a step per sample; a larger
    change is a glitch, a gap in the log or a channel that is not a low-resolution reading,
    and would otherwise end as an untrusted fit that blames the wrong cause.
    """
    change = np.diff(np.asarray(counts, dtype=np.int64))
    bad = np.flatnonzero(np.abs(change) > MAX_COUNT_CHANGE)
    if bad.size:
        i = int(bad[0]) + 1
        more = f" (and {bad.size - 1} more such changes)" if bad.size > 1 else ""
        raise ValueError(
            f"{where}, sample {i} (t = {t[i]:.6g} s): the count changes by {int(change[i - 1]):+d} "
            f"in one sample ({int(counts[i - 1])} -> {int(counts[i])}){more}; the dwell-pattern "
            f"fit needs the motion to move less than a step per sample (at most "
            f"{MAX_COUNT_CHANGE} counts between samples): a glitch or a gap in the log? Fix the "
            "file or crop the log to exclude it (crop: t_start/t_end).")


def analyse_lrde_log(df: pd.DataFrame, meta: dict, seed, settings: dict,
                     references: dict | None = None, threads: int = 1):
    """Dwell baselines and the Bayesian fit of one canonical log.

    Parameters
    ----------
    df : pandas.DataFrame
        Canonical log: ``t`` (s) and one column per channel.
    meta : dict
        Canonical metadata (``channels``: ``name, role, joint, unit, storage, step``;
        ``log_id`` optional).
    seed : int
        Root seed of the fit and of the posterior-predictive draws.
    settings : dict
        See the module docstring.
    references : dict, optional
        Per measured channel, what the residual stage found on it against the truth channel
        (:func:`enclab.reference_effects.lrde_reference`). The encoder and clock terms it
        names enter the final fit even when the held-out comparison did not choose them, and
        the report sets each term of the fit against the reference (``model.reference``).
    threads : int
        Processes for the comparison's point fits and the emcee fits: with 2 or more, the
        candidates' fits run side by side, and so do the paper's sinusoid (``before``), the
        final model (``after``) and the pooled alternatives, and the loop model's
        ensembles (the first round beside the sinusoid's fit; each depends only on the
        comparison and its own seed, so the results are the same as with 1).

    Returns
    -------
    block : dict
        The ``lrde`` block of ``summary.json`` (:func:`enclab.lrde.report.summary_block`)
        plus ``channels`` (what was used).
    figures : dict of str to matplotlib.figure.Figure
        ``"corner"``, ``"dwell_ppc"``, ``"bias_cycles"`` (paper 002 Fig. 6 from the log) and
        ``"misfit"`` (the localized check of the chosen model).
    report_md : str
    cycles : pandas.DataFrame
        :func:`enclab.lrde.dwell.cycle_table` of the measured counts.
    """
    if "t" not in df.columns:
        raise ValueError("df must have a time column 't' in seconds")
    settings = dict(settings or {})
    unknown = set(settings) - _KNOWN_SETTINGS
    if unknown:
        raise ValueError(f"unknown lrde settings {sorted(unknown)}; known: "
                         f"{sorted(_KNOWN_SETTINGS)}")
    t = df["t"].to_numpy(dtype=float)
    counts, step, truth, info = select_channels(df, meta, settings)
    source = (meta.get("source") or {}).get("file") or meta.get("log_id") or "the log"
    where = (f"{source}: column {info['measured']!r}" if info["measured"] else
             f"{source}: column {info['truth']!r} re-quantized")
    check_count_changes(t, counts, where)
    f_hz = settings.get("f_hz")
    root = np.random.SeedSequence(seed)
    # A sixth child for the loop model: the first five are those of a five-way spawn.
    fit_seed, ppc_seed, compare_seed, after_seed, alternatives_seed, loop_seed = root.spawn(6)
    try:
        cycles = dwell.cycle_table(counts, t, step, f_hz=f_hz)
        summary = dwell.dwell_summary(cycles)
        # The comparison first: its point fit of the sinusoid starts the ensembles near the
        # posterior, so that a short burn-in suffices.
        model_block, comparison = _compare_effects(t, counts, step, compare_seed, settings,
                                                     threads)
    except ValueError as err:  # what in these readings stops the fit, and where they are
        raise ValueError(f"{where}: {err}") from err
    reference = (references or {}).get(info["measured"]) if info["measured"] else None
    harmonics = tuple(comparison["chosen_harmonics"]) if comparison else ()
    chosen = tuple(comparison["chosen_effects"]) if comparison else ()
    added = [e for e in (reference or {}).get("effects", [])
             if e in lrde_effects.EFFECTS and e not in chosen]
    common = {"f_hz": f_hz, "truth": truth if settings.get("use_truth", True) else None,
              "truth_step": info.get("truth_step"),
              "rest_position": settings.get("rest_position"), **_sampler_settings(settings)}
    before_kw = {"start": None if comparison is None
                 else comparison["full_fits"]["sinusoid"]["x"], **common}
    # With a declared command or reference channel, the loop structures (the angle as the
    # logged error through a low-order filter) enter the held-out comparison against the
    # periodic pick; a winning structure's posterior gives the reported estimates, and the
    # periodic pick's own posterior and its alternatives are then not sampled.
    command, loop_not_offered = loop_command(df, meta, info, source)
    if loop_not_offered:
        _log.warning("%s: %s", source, loop_not_offered)
    structures = list(settings.get("loop_models", list(lrde_loop.STRUCTURES)))
    loop_cmp = loop_fit = None
    if command is not None and comparison is not None and structures:
        compare_loop_seed, fit_loop_seed = loop_seed.spawn(2)
        try:
            loop_cmp = lrde_loop.compare_loop_models(
                t, counts, command, step, comparison, structures,
                effects=[e for e in lrde_effects.check_effects(
                    settings.get("effects", lrde_effects.EFFECTS))
                    if e in lrde_loop.LOOP_EFFECTS],
                trust_z=float(settings.get("trust_z", compare.DEFAULT_TRUST_Z)),
                seed=compare_loop_seed, threads=threads)
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from err
    loop_chosen = loop_cmp is not None and loop_cmp["chosen"] is not None
    point, after_kw, alternatives = None, None, []
    if not loop_chosen:
        if added:
            # The truth channel saw an effect the readings alone did not resolve: the final
            # model is the comparison's choice plus that effect, from its own optimum.
            point = fit.map_fit(t, counts, step, f_hz=f_hz, harmonics=harmonics,
                                effects=chosen + tuple(added),
                                start=None if comparison is None
                                else comparison["full_fits"][comparison["chosen"]]["x"],
                                sigma_range=settings.get("sigma_range_steps"),
                                sigma_prior=settings.get("sigma_prior", "uniform"))
        elif harmonics or chosen:
            point = comparison["full_fits"][comparison["chosen"]]
        alternatives = _alternative_kwargs(t, counts, step, comparison, added, common,
                                           settings)
    jobs = [(fit_seed, before_kw)]
    jobs += list(zip(alternatives_seed.spawn(len(alternatives)), alternatives))
    if point is not None:
        after_kw = {"harmonics": harmonics, "effects": chosen + tuple(added),
                    "start": point["x"], **common}
        jobs.append((after_seed, after_kw))
    loop_plans, loop_label, loop_added = [], None, []
    if loop_chosen:
        # The truth channel's encoder terms join the loop structure as they join the
        # periodic pick (one term per structure); the same for its alternatives, which are
        # fitted beside it (their seeds follow the pick's, which they leave as it is).
        loop_label, loop_added = _loop_with_reference(loop_cmp["chosen"], added)
        labels = [loop_label]
        for alternative in loop_cmp.get("alternatives", []):
            label = _loop_with_reference(alternative, added)[0]
            if label not in labels:
                labels.append(label)
        sampler = _sampler_settings(settings)
        seeds = [fit_loop_seed] + loop_seed.spawn(len(labels) - 1)
        loop_plans = [lrde_loop.plan_loop_fit(  # own point fit for a structure not compared
            t, counts, command, step, seed_i, label, start=loop_cmp["fits"].get(label),
            n_ensembles=sampler["n_ensembles"], max_steps=max(sampler["max_steps"], 250),
            truth=common["truth"], truth_step=common["truth_step"])
            for seed_i, label in zip(seeds, labels)]
    try:
        # The loop's first round of ensembles shares one pool with the sinusoid's fit: the
        # sinusoid alone, then the ensembles, would leave a core idle.
        done = _run_fits(t, counts, step, jobs, threads,
                         beside=[call for plan in loop_plans for call in plan.calls])
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from err
    fits = done[:len(jobs)]
    result = fits[0]
    chosen_fit = fits[-1] if after_kw is not None else None
    loop_fits, first = [], len(jobs)
    for plan in loop_plans:
        loop_fits.append(plan.finish(done[first:first + len(plan.calls)], threads))
        first += len(plan.calls)
    if loop_fits:
        loop_fit = loop_fits[0]
    # Models the held-out comparison cannot tell from the pick (or, when it keeps the
    # sinusoid, does not rule out): their posteriors are pooled with the pick's (equal
    # weights), so the reported intervals do not hang on the pick.
    alternative_fits = fits[1:1 + len(alternatives)]
    pick = result if chosen_fit is None else chosen_fit
    averaged = fit.pool_fits([pick] + alternative_fits) if alternative_fits else None
    # The wall time goes to the log, not the block: summary.json must be byte-reproducible.
    _log.info("emcee fit: %.1f s wall, acceptance %.2f", result.wall_time_s, result.acceptance)
    before = result
    if comparison is not None or added:
        jump = None
        if chosen_fit is not None:
            _log.info("emcee fit of %s: %.1f s wall", chosen_fit.label, chosen_fit.wall_time_s)
            if lrde_effects.offsets_counts(point["effects"]):
                index, delta, mass, _ = lrde_effects.jump_posterior(
                    point["x"], t, counts, step, point["centre"], point["t_ref"],
                    point["harmonics"], point["effects"])
                jump = {"index": index, "time_s": float(t[index]), "delta": delta,
                        "probability_within_1_sample": mass,
                        "frame": "a_eq refers to the longer segment; the shorter one reads "
                                 f"{delta:+d} count"}
        if comparison is not None:
            model_block = report.effect_model_block(
                comparison, chosen_fit, duration_s=float(t[-1] - t[0]), jump=jump,
                averaged_over=None if averaged is None else averaged.settings["pooled"])
        else:
            model_block = dict(model_block, params=report.effect_params(
                chosen_fit, float(t[-1] - t[0]), jump))
        if added:
            model_block["effects"] = list(chosen) + added
            model_block["signature"] = {e: lrde_effects.effect_signature(e)
                                        for e in model_block["effects"]}
        if chosen_fit is not None:
            result = chosen_fit
    if loop_fit is not None:
        model_block = _loop_model_block(model_block, loop_cmp, loop_fit, loop_label,
                                        loop_added)
        _log.info("emcee fit of %s: %.1f s wall", loop_fit.label, loop_fit.wall_time_s)
        # The pick's alternatives (the loop comparison's ``alternatives``) are pooled with it
        # as the periodic pick's are: a plain filter and one with a narrow dead band read a
        # log alike, with strokes apart by more than their widths.
        result = loop_fit
        averaged = fit.pool_fits(loop_fits) if len(loop_fits) > 1 else None
        if averaged is not None:
            model_block["indistinguishable"] = [f.label for f in loop_fits[1:]]
            model_block["averaged_over"] = list(averaged.settings["pooled"])
            alternatives = model_block["indistinguishable"]
            model_block["note"] += (
                f"; {', '.join(alternatives)} score{'s' if len(alternatives) == 1 else ''} "
                f"on held-out cycles no more than {loop_cmp['min_z']:g} standard errors "
                f"below {loop_fit.label}, or better: the reported estimates pool their "
                f"posteriors with equal weights ('after' is {loop_fit.label} alone)")
    elif loop_cmp is not None:
        model_block["loop"] = loop_cmp["models"]
        model_block["loop_rule"] = loop_cmp["rule"]
    elif loop_not_offered:
        model_block["loop_not_offered"] = loop_not_offered
    if reference is not None:
        model_block["reference"] = report.reference_block(
            reference, model_block, loop_added if loop_fit is not None else added)
    reported = averaged if averaged is not None else result
    block = report.summary_block(reported, summary)
    block["channels"] = info
    block["model"] = model_block
    block["before"] = report.estimates_block(before)
    block["after"] = report.estimates_block(result)
    if averaged is not None:
        block["averaged"] = report.estimates_block(averaged)
    block["trust"] = report.trust_block(reported, model_block)
    residuals = report.effect_residuals_block(model_block)
    if residuals is not None:
        block["residuals"] = residuals
    if loop_fit is not None:
        predictive = lrde_loop.posterior_predictive_dwell(
            loop_fit, t, counts, command, ppc_seed, n_draws=int(settings.get("ppc_draws", 40)))
    else:
        predictive = plots.posterior_predictive_dwell(
            result, t, ppc_seed, n_draws=int(settings.get("ppc_draws", 40)))
    truth_periods = None
    if truth is not None and block["offset_a"] is not None and block["centre_count"] is not None:
        truth_periods = plots.truth_bias_deviation(
            t, truth, block["f_hz"]["median"], step, block["offset_a"]["median"],
            block["centre_count"])
    figures = {"corner": (plots.loop_corner_plot(loop_fit) if loop_fit is not None
                          else plots.corner_plot(result)),
               "dwell_ppc": plots.dwell_ppc_plot(cycles, predictive),
               "bias_cycles": plots.bias_cycles_plot(
                   cycles, step, truth_periods,
                   fitted={"E_b": block["E_b"], "label": model_block.get("chosen", "sinusoid")}),
               "misfit": plots.misfit_plot(None if comparison is None or loop_fit is not None
                                           else comparison["trace_detail"])}
    report_md = report.report_markdown(block, meta.get("log_id"))
    return block, figures, report_md, cycles
