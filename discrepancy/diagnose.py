"""The mismatch diagnosis: compare -> calibrate -> locate -> name -> generic route -> model and show.

:func:`diagnose` is the whole pipeline; :mod:`discrepancy.report` writes it out.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sam import Plant
from sam.recording import Recording

from . import locate as loc
from .data import check_same_plant, check_segment, missing_note, prepare, sampling_note, sensor_limits
from .design import Design, settle
from .fitting import (FitResult, Model, Split, correlation_time, evaluate, fit_by_segment, segment_delta_bic, segment_rss,
                      segment_scales, unweighted)
from .ceiling import closest_library_effect, excess, noise_ceiling, short_of_ceiling
from .commissioning import calibrate, calibration_params, commissioning_start
from .generic import generic_route
from .floor import Floor, Specificity, specific, start_sensitive, step_floor
from .library import Free, Hypothesis, format_value, library
from .report import write
from .resolvable import resolvable
from .settings import Settings
from .simulation import SIGNALS, SegmentSimulator, fits
from .verdict import unscored_note, verdict_of

#: A hypothesis is accepted when its BIC falls by more than this...
BIC_STRONG = 10.0
#: ...and it removes at least this share of the weighted squared error, on the fitting part and held out.
MIN_GAIN = 0.05
#: ...and it raises the mean held-out fit by at least this many percentage points (practical significance:
#: below it the remaining residual is at the level of noise and of the segment start-up transients).
MIN_FIT_POINTS = 0.5
#: How many hypotheses enter the second (two-effect) round.
SECOND_ROUND = 4
_DEBUG = bool(__import__("os").environ.get("DISCREPANCY_DEBUG"))


@dataclass
class Candidate:
    hypothesis: list[Hypothesis]
    result: FitResult
    delta_bic: float
    gain_fit: float  # relative reduction of the weighted squared error, fitting part
    gain_held: float  # same, held out
    signature: float  # 0..1 match of its sensitivity signature with the located residual
    accepted: bool = False
    delta_bic_all: float = 0.0
    delta_bic_held: float = 0.0  # BIC change on the held-out part alone (the out-of-sample evidence)
    seg_bic_fit: float = 0.0  # BIC change with one residual variance per segment, fitting part
    seg_bic_held: float = 0.0  # same, held out
    fit_before: dict = field(default_factory=dict)
    fit_after: dict = field(default_factory=dict)
    specificity: Specificity | None = None  # its held-out gain segment by segment, against the step floor
    physical: bool = True  # moves a nominal value by > 5 % and a lag or delay by >= one sample

    @property
    def name(self) -> str:
        return " + ".join(h.name for h in self.hypothesis)

    @property
    def title(self) -> str:
        return " + ".join(h.title for h in self.hypothesis)

    def effect_values(self) -> dict[str, float]:
        names = {f.name for h in self.hypothesis for f in h.params}
        return {k: v for k, v in self.result.values.items() if k in names}

    def summary(self) -> str:
        vals = self.result.values
        return "; ".join(h.summary(vals) for h in self.hypothesis)


@dataclass
class Report:
    """Everything the diagnosis found; :func:`discrepancy.report.write` renders it."""

    source: str
    validate_source: str | None
    verdict: str  # 'adequate', 'recalibrated', 'named', 'unknown_effect', 'unexplained'
    headline: str
    fit_table: dict  # model -> part -> signal -> fit %
    calibration: list[dict]
    located: dict
    ranked: list[Candidate]
    chosen: list[Candidate]
    generic: dict | None
    warnings: list[str]
    timings: dict
    figures: list[str] = field(default_factory=list)
    n_eff: float = 0.0
    segment_s: float = 1.0  # length of the simulation segments [s]
    floor: Floor | None = None  # the share of the calibrated error the model's own step accounts for
    sureness: dict = field(default_factory=dict)  # the runner-up of the first named effect and its margin
    design: Design | None = None  # the input that would tell the first named effect from its look-alike
    limits: list[str] = field(default_factory=list)  # what the sensor set and sampling rate cannot tell apart
    plant_path: str | None = None  # the plant file, for the designed scenario
    shortfall: dict = field(default_factory=dict)  # the held-out noise ceiling and the calibrated model's excess
    notes: list[str] = field(default_factory=list)  # what was left out of the judgement, said where it matters
    traces: dict = field(default_factory=dict)  # for figures

    @property
    def named(self) -> list[str]:
        return [h.name for c in self.chosen for h in c.hypothesis]


def _calibration_changes(free: tuple[Free, ...], nominal: dict, fitted: FitResult) -> list[dict]:
    out = []
    for f in free:
        a, b = nominal[f.name], fitted.values[f.name]
        rel = (b - a) / a if (f.log and a) else b - a
        out.append({"parameter": f.name, "label": f.label, "nominal": a, "calibrated": b,
                    "change": rel, "relative": f.log, "at_bound": f.name in fitted.at_bounds,
                    "text": f"{f.label}: {format_value(a, f.unit)} -> {format_value(b, f.unit)}"})
    return out


def diagnose(rec: Recording, plant: Plant, out_dir: str | Path | None = None, validate: Recording | None = None,
             *, seg_s: float = 1.0, figures: bool = True, generic: bool = True,
             settings: Settings = Settings(), plant_path: str | Path | None = None) -> Report:
    """Diagnose where and why ``plant`` fails to reproduce ``rec``; write the report to ``out_dir``.

    ``plant_path``: the plant file ``plant`` was read from, named in the designed scenario
    (``separate.toml``) so that ``samfdi simulate`` runs it on the same plant; None: the default."""
    t_start = time.perf_counter()
    plant = plant.replace(arm_rate_torque=settings.arm_rate_torque)
    timings = {}
    warnings: list[str] = []
    notes: list[str] = []
    data = prepare(rec, plant, settings=settings)
    warnings.extend(filter(None, [missing_note(data)]))
    if validate is not None:
        vdata = prepare(validate, plant, role="validation recording", min_duration=1.0, settings=settings)
        warnings.extend(filter(None, [missing_note(vdata)]))
        check_same_plant(data, vdata, plant, str(validate.source or "validation recording"))
        check_segment(seg_s, data, vdata)
        if note := sampling_note(data, vdata):
            warnings.append(note)
        split = Split(SegmentSimulator(data, seg_s, held_out_every=10**9, scheme=settings.scheme),
                      SegmentSimulator(vdata, seg_s, all_held_out=True, scheme=settings.scheme))
    else:
        check_segment(seg_s, data)
        split = Split(SegmentSimulator(data, seg_s, scheme=settings.scheme))
    fsim = split.fit_sim

    # ---- compare: nominal, then calibrate the GSA-ranked nominal parameters
    calib = calibration_params(plant)
    base = plant.vector()
    cal_model = Model(base, calib)
    nominal_values = cal_model.values_of(cal_model.theta_of({}))
    restart = commissioning_start(data, plant, calib, settings)
    # segments whose error the start state decides (trapped oil at null) judge nothing: not scored
    start_params = cal_model.build(cal_model.theta_of(restart)[None, :])[0][0]
    for sim in {id(s): s for s in (split.fit_sim, split.held_sim)}.values():
        unsure = start_sensitive(sim, start_params, settings)
        sim.unscore(unsure)
        if unsure.any():  # a note, not a warning: report.console_lines says it where it matters
            notes.append(unscored_note(sim.data.name, sim.data.t[sim.seg.starts[unsure]], len(unsure),
                                       settings.start_shift_s))
    cal = calibrate(split, plant, calib, restart, settings)
    calibration = _calibration_changes(calib, nominal_values, cal)
    floor = step_floor(split, cal, settings)
    for c in calibration:
        if c["at_bound"]:
            warnings.append(f"calibrated {c['parameter']} hit its bound ({c['text']}): the nominal plant may be far off")
    timings["calibrate_s"] = time.perf_counter() - t_start

    # ---- locate: residual of the calibrated model
    cal_full = fsim.simulate(cal.params[None, :], full=True)
    res = loc.full_residual(fsim, cal_full)
    energy = sum(np.nan_to_num(res[k]) ** 2 for k in SIGNALS)
    energy[np.isnan(res["pA"])] = np.nan
    masks = loc.regimes(data, plant.supply.p_S, plant.cylinder.x_max)
    sig_share = {k: float(np.nansum(res[k] ** 2) / max(np.nansum(energy), 1e-30)) for k in SIGNALS}
    located = {
        "signal_share": sig_share,
        "windows": loc.windows(energy, data.t, data.dt),
        "regimes": loc.regime_profile(energy, masks),
        "whiteness": {k: loc.whiteness(res[k]) for k in SIGNALS},
        "input_correlation": {k: loc.input_correlation(res[k], data.u, data.dt) for k in SIGNALS},
    }
    r_cal_fit = evaluate(split, cal_model, cal_model.theta_of(cal.values)[None, :], "fit")[0]
    n_blocks = 3 * int(np.sum(fsim.segment_mask("fit")))
    tau = correlation_time(r_cal_fit, n_blocks)
    n_eff = max(cal.n_fit / tau, 10.0)
    # the recording's noise ceiling and the calibrated model's excess over it (discrepancy.ceiling)
    ceiling = noise_ceiling(split.sim_for("held"))
    cal_held = _held_fits(split.settled(settings.start_decay_times), cal)["mean"]
    limit = settings.excess_limit
    shortfall = {"ceiling_held": ceiling, "calibrated_held": cal_held, "excess": excess(cal_held, ceiling["mean"]),
                 "limit": limit, "calibrated_short": short_of_ceiling(cal_held, ceiling["mean"], limit)}
    gate = _Gate(floor, settings, n_eff / split.n_segments("fit"), ceiling["mean"], shortfall["calibrated_short"])
    timings["locate_s"] = time.perf_counter() - t_start

    # ---- name: signatures, then fit every hypothesis jointly with the calibration parameters
    hyps = library(plant, frozenset(f.name for f in calib))
    sig = _signatures(split, cal, calib, hyps, r_cal_fit)
    cands = []
    for h in hyps:
        cands.append(_fit_hypothesis(split, cal, calib, [h], n_eff, sig.get(h.name, 0.0), gate, restart=restart))
    cands.sort(key=_rank_key)
    if _DEBUG:
        print(f"   floor: held {floor.pooled:.4f} fit {floor.pooled_fit:.4f}; n_seg_eff {gate.n_seg_eff:.0f}")
        for c in cands:
            sp = c.specificity
            print(f"   1st {c.name}: acc {c.accepted} dBIC {c.delta_bic:.0f} segh {c.seg_bic_held:.0f} "
                  f"gf {c.gain_fit:.3f} gh {c.gain_held:.3f} spec {sp.passed} act {sp.active.sum()}/{len(sp.active)} "
                  f"gains {np.array2string(sp.gain, precision=3)} {c.summary()}")
    accepted = [c for c in cands if c.accepted]
    chosen: list[Candidate] = []
    if accepted:
        first = accepted[0]
        chosen.append(first)
        # second round (forward selection): a second effect on top of the first.
        # The reference is the first effect re-fitted from its own optimum (so that a second effect is not
        # credited with what more optimiser iterations give the first), and the candidates are chosen by
        # their score test against the residual *left by the first*, with the calibration and the first
        # effect's parameters projected out (an effect masked by a stronger one shows only there).
        # Heteroscedastic segments: the residual variance of each 1 s segment is estimated once from the
        # first effect's fit (feasible GLS, see fitting.segment_scales), and everything in this round
        # (the re-fitted first effect, the score test, the pair fits, the BIC on both parts) is computed
        # under it: one segment with a large start-up error must not decide which second effect is found.
        ref0 = _refit(split, cal, calib, first, [first.result], settings)
        m1 = Model(cal.params, _free_of(calib, first.hypothesis), cal.meas)
        wsplit = split.weighted(segment_scales(split, m1, m1.theta_of(ref0.values)))
        ref1 = _refit(wsplit, cal, calib, first, [ref0], settings)
        r1 = evaluate(wsplit, Model(ref1.params, (), ref1.meas), np.zeros((1, 0)), "fit")[0]
        n_eff2 = max(ref1.n_fit / correlation_time(r1, n_blocks), 10.0)
        rest = [h for h in hyps if h.name not in {x.name for x in first.hypothesis}]
        sig2 = _signatures(wsplit, ref1, _free_of(calib, first.hypothesis), rest, r1)
        by_sig = sorted(rest, key=lambda h: -sig2.get(h.name, 0.0))[:SECOND_ROUND - 1]
        by_bic = [c.hypothesis[0] for c in cands if c is not first and c.delta_bic < -BIC_STRONG][:2]
        pool = []
        for h in by_sig + by_bic:
            if h not in pool:
                pool.append(h)
        first_round = {c.name: c for c in cands}
        best2 = None
        for h in pool:
            c1 = first_round[h.name]
            c2 = _fit_hypothesis(wsplit, cal, calib, first.hypothesis + [h], n_eff2, sig2.get(h.name, 0.0), gate,
                                 start_from=[ref1, c1.result], reference=ref1, second=True)
            if c2.accepted:
                # ablation: the first effect alone, re-fitted from the pair's optimum; the second must still
                # pass every test against it (it has to earn its gain on its own, held out included)
                abl = _refit(wsplit, cal, calib, first, [c2.result], settings)
                if abl.rss_fit < ref1.rss_fit:
                    c2 = _judge(wsplit, first.hypothesis + [h], c2.result, abl, n_eff2, c2.signature, gate, second=True)
            if _DEBUG:
                print(f"   2nd {h.name}: sig {sig2.get(h.name, 0):.2f} acc {c2.accepted} dBIC {c2.delta_bic:.0f} "
                      f"dBICh {c2.delta_bic_held:.0f} neff {n_eff2:.0f} "
                      f"gf {c2.gain_fit:.2f} gh {c2.gain_held:.2f} fit {c2.fit_before['mean']:.1f}->{c2.fit_after['mean']:.1f} "
                      f"{c2.summary()}")
            if c2.accepted and (best2 is None or c2.delta_bic_held < best2.delta_bic_held):
                best2 = c2
        if best2 is not None:
            best2.result = unweighted(split, best2.result)
            chosen = [best2]
    timings["name_s"] = time.perf_counter() - t_start

    final = chosen[0].result if chosen else cal
    # ---- generic route on what remains
    gen = None
    if generic:
        gen = generic_route(split, data, cal, calib, n_eff, hyps, settle=settings.start_decay_times)
    timings["generic_s"] = time.perf_counter() - t_start
    if gen and gen.get("significant") and not gen["in_library"]:
        if chosen:
            c = chosen[0]
            k = len(c.result.free) - len(cal.free)
            dbic_c = n_eff * math.log(c.result.rss_fit / cal.rss_fit) + k * math.log(n_eff)
            gen["library_delta_bic"] = dbic_c
            if gen["delta_bic"] < dbic_c - BIC_STRONG:
                warnings.append(f"the best library effect ({c.name}) explains less than the generic term; "
                                f"it is reported as an alternative, not as the cause")
                gen["beats_library"] = True
                chosen = []
                final = cal
        else:
            gen["beats_library"] = True
    elif gen:
        gen["significant_but_library"] = bool(gen.get("significant"))
        if chosen:
            gen["significant"] = False  # a library effect already explains the residual
        elif gen.get("significant") and (c := _of_form(cands, gen.get("library_effect"))) is not None:
            # the generic term has a library effect's form: it is that effect, not an unknown one (its fitted
            # size is the library's); named when the effect's own fit predicts the held-out part better
            warnings.append(f"{c.name} is named through the generic route: its term {gen['equation']} has the form "
                            f"of {c.name}, whose own fit alone did not pass every acceptance test")
            gen["significant"] = False
            chosen, final = [c], c.result

    # ---- short of the noise ceiling: nothing named, yet the calibrated model errs far more than a clean
    # recording's does over its noise (discrepancy.ceiling): not adequate; the library's closest, else unknown
    shortfall["short"] = shortfall["calibrated_short"] and not chosen and not (gen and gen.get("significant"))
    if shortfall["short"]:
        if (c := closest_library_effect(cands, ceiling["mean"], limit, BIC_STRONG, MIN_GAIN, MIN_FIT_POINTS)):
            warnings.append(f"{c.name} is named because the calibrated model errs {shortfall['excess']:.1f} times the "
                            f"recording's noise (clean recordings: at most {limit:g}) and it alone brings the held-out "
                            f"fit to {c.fit_after['mean']:.1f} %, though it did not pass every acceptance test")
            chosen, final = [c], c.result

    # ---- verdict
    fit_table = _fit_table(split.settled(settings.start_decay_times),
                           {"nominal": (base, np.zeros(2)), "calibrated": (cal.params, cal.meas),
                            **({"augmented": (final.params, final.meas)} if chosen else {})},
                           gen if (gen and gen.get("significant")) else None)
    for c in chosen:
        for name in c.result.at_bounds:
            warnings.append(f"fitted {name} of '{c.name}' sits at its bound: the true value may lie beyond it")
    verdict, headline = verdict_of(chosen, calibration, gen, fit_table, located, shortfall)
    sureness, design = settle(split, data, cands, chosen, plant, settings.scheme, BIC_STRONG)
    timings["settle_s"] = time.perf_counter() - t_start
    report = Report(
        source=str(rec.source or "recording"), validate_source=str(validate.source) if validate is not None else None,
        verdict=verdict, headline=headline, fit_table=fit_table, calibration=calibration, located=located,
        ranked=cands, chosen=chosen, generic=gen, warnings=warnings, timings=timings, n_eff=n_eff,
        segment_s=fsim.seg.length * data.dt, floor=floor, sureness=sureness, design=design,
        limits=sensor_limits(data), plant_path=str(plant_path) if plant_path is not None else None,
        shortfall=shortfall, notes=notes,
    )
    report.traces = {"split": split, "nominal": base, "calibrated": cal, "final": final, "residual": res,
                     "masks": masks, "energy": energy}
    timings["total_s"] = time.perf_counter() - t_start
    if out_dir is not None:
        write(report, Path(out_dir), figures=figures)
        timings["total_s"] = time.perf_counter() - t_start
    return report


def _free_of(calib, hyps) -> tuple[Free, ...]:
    """The calibration parameters followed by every parameter of ``hyps``."""
    return tuple(calib) + tuple(f for h in hyps for f in h.params)


def _refit(split: Split, cal: FitResult, calib, first: Candidate, starts: list[FitResult],
           settings: Settings) -> FitResult:
    """The first effect (with the calibration parameters) fitted again on ``split`` from the best of
    ``starts`` (fits whose values of the same parameters are used; the first's own optimum fills gaps)."""
    model = Model(cal.params, _free_of(calib, first.hypothesis), cal.meas)
    vals = {**cal.values, **first.result.values}
    thetas = [model.theta_of({**vals, **{k: v for k, v in s.values.items() if k in vals}}) for s in starts]
    return fit_by_segment(split, model, thetas, settings.hypothesis_nfev, settings.segment_rounds,
                          settings.segment_round_nfev)


def _of_form(cands: list[Candidate], effect: str | None) -> Candidate | None:
    """The first-round candidate of the library effect ``effect`` (the generic route's term has its
    form), if its fit raises the held-out fit and lowers the held-out error; else None."""
    for c in cands:
        if c.name == effect and c.gain_held > 0.0 and c.fit_after.get("mean", 0.0) > c.fit_before.get("mean", 0.0):
            return c
    return None


def _rank_key(c: Candidate):
    # accepted (strong BIC on the fitting part, confirmed held out) first; then the BIC change on the
    # held-out part: the fitting part has already been used to fit the parameters, so between accepted
    # hypotheses (each strongly better there) the out-of-sample evidence decides; the signature breaks ties.
    # An accepted effect that helps on every held-out segment it changes ranks before one accepted only
    # through rule 3's most-segments path (an approximate form: dev seal friction 4e-4 m^2 was named a
    # friction level that failed a segment, ahead of the exact seal form, by 58 in held-out BIC)
    specific = c.accepted and c.specificity is not None and bool(c.specificity.passed)
    return (not c.accepted, not specific, round(c.delta_bic_held, 0), -c.signature)


@dataclass(frozen=True)
class _Gate:
    """What an effect's evidence is judged against besides the BIC: the step floor, the settings, and
    the effective samples of one segment (floor.specific)."""

    floor: Floor
    settings: Settings
    n_seg_eff: float
    ceiling: float = 100.0  #: % the held-out noise ceiling's mean (discrepancy.ceiling.noise_ceiling)
    short: bool = False  #: the calibrated model errs more than Settings.excess_limit times the ceiling's shortfall


def _fit_hypothesis(split: Split, cal: FitResult, calib, hyps: list[Hypothesis], n_eff: float, signature: float,
                    gate: _Gate, start_from: list[FitResult] | None = None, reference: FitResult | None = None,
                    second: bool = False, restart: dict | None = None) -> Candidate:
    reference = reference or cal
    free = tuple(calib) + tuple(f for h in hyps for f in h.params)
    model = Model(cal.params, free, cal.meas)
    base_vals = dict(cal.values)
    starts, families = [], None
    if start_from:
        merged = dict(base_vals)
        for r in start_from:
            merged.update({k: v for k, v in r.values.items() if k not in base_vals})
        merged.update({k: v for k, v in start_from[0].values.items() if k in base_vals})
        starts.append(model.theta_of(merged))
        for h in hyps[len(hyps) - 1:]:
            for s in h.starts:
                starts.append(model.theta_of({**merged, **s}))
    else:
        # from the calibrated values, and from the commissioning start: the calibration may have absorbed
        # part of the effect (a lower notch flow for a flow limit), which the effect's fit must be free to undo.
        # The best start of each family of the hypothesis' starts is optimised (fitting.fit)
        families = []
        for h in hyps:
            for family in h.families:
                first = len(starts)
                for s in family:
                    starts.append(model.theta_of({**base_vals, **s}))
                    if restart:
                        starts.append(model.theta_of({**restart, **s}))
                families.append(list(range(first, len(starts))))
    st = gate.settings
    res = fit_by_segment(split, model, starts, st.hypothesis_nfev, st.segment_rounds, st.segment_round_nfev,
                         families)
    return _judge(split, hyps, res, reference, n_eff, signature, gate, second)


def _judge(split: Split, hyps: list[Hypothesis], res: FitResult, reference: FitResult, n_eff: float,
           signature: float, gate: _Gate, second: bool = False) -> Candidate:
    """Evidence of a fitted hypothesis against a reference fit: BIC, gains, held-out fit, acceptance.

    Both are judged with every segment started from the state consistent with each
    (``Settings.start_decay_times``, :meth:`SegmentSimulator.settled_states`): a segment whose error
    is its start's would otherwise count against (or for) whichever model rings less from it."""
    split = split.settled(gate.settings.start_decay_times)
    rss = {id(r): _rss(split, r) for r in (res, reference)}
    (new_fit, new_held), (ref_fit, ref_held) = rss[id(res)], rss[id(reference)]
    k = len(res.free) - len(reference.free)
    dbic = n_eff * math.log(max(new_fit, 1e-300) / ref_fit) + k * math.log(n_eff)
    gain_fit = 1 - new_fit / ref_fit
    gain_held = 1 - new_held / ref_held
    c = Candidate(list(hyps), res, dbic, gain_fit, gain_held, signature)
    # evidence on all the data (fitting part and held out), for ranking the accepted ones
    n_all = n_eff * (res.n_fit + res.n_held) / res.n_fit
    c.delta_bic_all = n_all * math.log(max(new_fit + new_held, 1e-300) / (ref_fit + ref_held)) + k * math.log(n_all)
    n_h = max(n_eff * res.n_held / res.n_fit, 10.0)
    c.delta_bic_held = n_h * math.log(max(new_held, 1e-300) / ref_held) + k * math.log(n_h)
    # segment-wise profile likelihood: each 1 s segment has its own residual variance (profiled out), so
    # the log-likelihood change is a sum over segments of log RSS ratios and every segment counts by its
    # effective sample size, not by the size of its error (one segment with a large start-up error cannot
    # carry an effect)
    c.seg_bic_fit, c.seg_bic_held = (_segment_delta_bic(split, res, reference, part, n_eff, k) for part in ("fit", "held"))
    if second:
        c.delta_bic, c.delta_bic_held = c.seg_bic_fit, c.seg_bic_held
    c.fit_before, c.fit_after = (_held_fits(split, r) for r in (reference, res))
    # strong statistical evidence, on the fitting part and out of sample on the held-out part
    evidence = c.seg_bic_fit < -BIC_STRONG and c.seg_bic_held < -BIC_STRONG
    if not second:
        # a first effect must also matter in practice: before the nominal model is declared inadequate, the
        # effect has to remove a visible share of the error (both parts) and raise the held-out fit
        evidence = (evidence and dbic < -BIC_STRONG and gain_fit > MIN_GAIN and gain_held > MIN_GAIN
                    and c.fit_after["mean"] - c.fit_before["mean"] >= MIN_FIT_POINTS)
    # and beat the model's own error specifically: on every held-out segment where it changes the
    # prediction (or, when the calibrated model is far short of its noise ceiling, on most, if it brings
    # the model back within the limit: discrepancy.ceiling), and by more than the step floor over the
    # held-out part (discrepancy.floor). Within the limit the rule is unchanged: a clean recording's
    # calibrated model is there, and an effect that helps on most segments may be fitting its error
    c.specificity = specific(split, res, reference, gate.floor, gate.n_seg_eff, gate.settings)
    c.physical = _away_from_nominal(hyps, res) and resolvable(hyps, res, split.fit_sim.data.dt, gate.settings)
    sp, st = c.specificity, gate.settings
    closes = not short_of_ceiling(c.fit_after["mean"], gate.ceiling, st.excess_limit)
    c.accepted = evidence and c.physical and (sp.passed or (gate.short and sp.mostly and closes))
    return c


def _rss(split: Split, r: FitResult) -> tuple[float, float]:
    """Squared error of the fit ``r`` on the fitting and the held-out part of ``split`` (its weights, its starts)."""
    none = np.zeros((1, 0))
    return tuple(float(np.sum(evaluate(split, Model(r.params, (), r.meas), none, part)[0] ** 2))
                 for part in ("fit", "held"))


def _held_fits(split: Split, r: FitResult) -> dict[str, float]:
    """Per-signal held-out fit % of the fit ``r``, every segment started as ``split`` starts it."""
    hs = split.sim_for("held")
    return fits(hs, hs.simulate(r.params[None, :], r.meas[None, :] if np.any(r.meas) else None,
                                settle=split.settle), "held")


def _segment_delta_bic(split: Split, res: FitResult, reference: FitResult, part: str, n_eff: float,
                       k: int) -> float:
    """BIC change of ``res`` over ``reference`` on one part with one residual variance per segment
    (:func:`fitting.segment_delta_bic`); a segment's effective sample size is n_eff (from the residual
    correlation time on the fitting part) over the number of fitting segments."""
    n_seg = split.n_segments(part)
    rss = [segment_rss(evaluate(split, Model(r.params, (), r.meas), np.zeros((1, 0)), part)[0], n_seg)
           for r in (res, reference)]
    return segment_delta_bic(rss[0], rss[1], n_eff / split.n_segments("fit"), k)


def _away_from_nominal(hyps: list[Hypothesis], res: FitResult) -> bool:
    """Every hypothesis whose parameters have a nominal value (load mass, friction levels) must move at
    least one of them by more than the calibration's own 5 % significance: an 'effect' fitted at its
    nominal value is no effect, its gain comes from re-tuning the calibration parameters."""
    for h in hyps:
        if not h.nominal:
            continue
        if not any(abs(res.values[n] / v - 1) > 0.05 for n, v in h.nominal.items() if v):
            return False
    return True


def _signatures(split: Split, cal: FitResult, calib, hyps, r_cal: np.ndarray) -> dict[str, float]:
    """Score-test match of each hypothesis' sensitivity with the calibrated residual (0..1).

    The sensitivity is the change of the simulated signals when the effect is
    switched on at a small realistic magnitude, with the part the calibration
    parameters could absorb projected out; the score is the |cosine| between
    it and the residual.
    """
    # calibration sensitivities
    model = Model(cal.params, calib, cal.meas)
    th = model.theta_of(cal.values)
    cands = np.repeat(th[None, :], len(th) + 1, axis=0)
    cands[1:][np.arange(len(th)), np.arange(len(th))] += 1e-2
    rr = evaluate(split, model, cands)
    J = (rr[1:] - rr[0]).T
    Q, _ = np.linalg.qr(J)
    r = -r_cal  # measured - simulated
    r_perp = r - Q @ (Q.T @ r)
    out = {}
    for h in hyps:
        hm = Model(cal.params, h.params, cal.meas)
        probe = hm.theta_of(h.probe)
        rp = evaluate(split, hm, probe[None, :])[0]
        s = rp - rr[0]
        s_perp = s - Q @ (Q.T @ s)
        den = np.linalg.norm(s_perp) * np.linalg.norm(r_perp)
        out[h.name] = float(abs(np.dot(s_perp, r_perp)) / den) if den > 0 else 0.0
    return out


def _fit_table(split: Split, models: dict, gen: dict | None) -> dict:
    """part -> signal -> fit % of each model, every segment started as ``split`` starts it."""
    table = {}
    for name, (params, meas) in models.items():
        table[name] = {}
        for part in ("fit", "held"):
            sim = split.sim_for(part)
            out = sim.simulate(params[None, :], meas[None, :] if np.any(meas) else None, settle=split.settle)
            table[name][part] = fits(sim, out, part)
    if gen is not None and "fit_table" in gen:
        table["generic"] = gen["fit_table"]
    return table
