"""The likelihood bank: constrained filters, one per fault hypothesis, run after an alarm.

Each hypothesis H of :data:`fdi.faults.BANK` (healthy, each single fault) or of the pairs is a
filter (:func:`bank_config`) in which only H's fault parameters are free, constant, with a
prior (:attr:`BankDesign.prior_sd`); the others are held at their healthy values (known
constants: the unscented transform runs over the free states only). All hypotheses of all runs
go through ONE :func:`fdi.filter.run_filter` call. Its innovation log-likelihood, summed over a
window, is each hypothesis' evidence (the Kalman predictive decomposition of p(y | H)).

The bank starts from a healthy reference filter (:func:`run_reference`): the detection filter
with every fault parameter held, whose calibration states (load mass, B_eff, notch flows) learn
the nuisance before the onset without being able to trade it against a fault. The onset itself
is a nuisance: banks start at several candidate onsets and each hypothesis' evidence is averaged
over them (:func:`run_bank_starts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .config import (
    CalibrationStates, Constraints, FilterConfig, Guards, FormNoise, Sensors, StopRules, UnknownInputStates,
)
from .faults import BANK, FAULTS, MULTI, PARAMS, free_states
from .filter import FilterOutput, run_filter, sample_step
from .states import K_PER_LPM, N_AUG, N_MODEL, SCALE, STATE_NAMES
from .whiteness import evidence_factor

#: the innovation channels of FilterOutput.nu, in order
CHANNELS = ("pA", "pB", "pos")

#: the fault states, FAULTS order
FAULT_IDX = tuple(PARAMS.values())


def _positive(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0.0 < value < math.inf


@dataclass(frozen=True)
class BankDesign:
    """How the likelihood bank is built and how it decides: the method's own settings, the same
    for every machine (the per-machine ones are in :class:`fdi.thresholds.Confirmation`)."""

    #: the filter whose calibration states learn the nuisance before the onset (its fault states
    #: are then held): the detection filter with a 1e-4 rad encoder floor
    reference: FilterConfig = field(default_factory=lambda: FilterConfig(
        sensors=Sensors(theta_noise_floor=1e-4), calibration=CalibrationStates(hold_after_s=None)))
    #: calibration states the confirmation bank carries as uncertain constants (in "none" too)
    #: instead of holding the reference's values: a notch not yet used in the record is still at
    #: its prior, and its error would look like a fault to a bank that holds it
    confirm_calibrate: tuple = ("m_L", "Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT")
    #: prior std of a free fault parameter (SI): the largest leak of interest (1 L/min) and the
    #: offset that changes the pressures as much (2 %)
    prior_sd: dict = field(default_factory=lambda: {"K_int": 1.0 * K_PER_LPM, "K_extA": 1.0 * K_PER_LPM,
                                                    "K_extB": 1.0 * K_PER_LPM, "offset": 0.02})
    held_p0_factor: float = 1e-6  #: the reference's prior std of a held fault state, x its detection prior
    frozen_var: float = 1e-12  #: reported variance of a held state (internal units)
    #: s: the bank starts this long before the CUSUM's change-time estimate (the residual needs a
    #: moment to leave 0 after a step; an early start only adds healthy samples to every hypothesis)
    onset_lead_s: float = 0.1
    start_step_s: float = 0.05  #: s: spacing of the candidate onsets after the first
    n_starts: int = 4  #: candidate onsets at most (never after the alarm)
    #: s: no decision before this long after the first candidate onset: the first tenths of a
    #: second after a step are a transient every hypothesis follows in its own way
    min_evidence_s: float = 0.6
    #: s: the bank judges an alarm over at most this long after it (the 1 s isolation target)
    decision_window_s: float = 1.0
    #: s: the several-faults stage runs at most this long after the alarm (one extension and retraction)
    pair_window_s: float = 4.0
    #: smallest change of a pair member that is reported (SI): the smallest sizes of interest;
    #: below it, what a constant-parameter model picks up from a fault that is not constant
    min_pair_size: dict = field(default_factory=lambda: {
        "K_int": 0.1 * K_PER_LPM, "K_extA": 0.1 * K_PER_LPM, "K_extB": 0.1 * K_PER_LPM, "offset": 0.01})
    #: a single fault is named only when its filter moved by this fraction of min_pair_size (a
    #: leak growing): a leak filter at 0 can still lead on the misfit it absorbed on the way
    min_single_fraction: float = 0.5
    #: the largest mean NIS over the several-faults window of a hypothesis that explains it: its
    #: expected value, 3 channels; a fault that is not constant fits no constant-fault filter
    fit_nis: float = 3.0
    #: withdrawn alarms after which a run's tests are no longer restarted, at the least (a longer
    #: record gets one per decision window: :func:`fdi.isolation.max_episodes`)
    max_episodes: int = 30
    #: s: longest lag of the innovations' autocorrelation counted in the evidence's honest size
    #: (:mod:`fdi.whiteness`; 0: every sample counts as independent): the decision window's
    #: length, as a model-form error (a flow the model draws otherwise) biases the innovations
    #: for as long as the operating point lasts, and a longer correlation cannot be told apart
    colour_lag_s: float = 0.5
    #: standard deviations of white noise's chance colour subtracted from the estimate: white
    #: innovations keep their whole evidence in all but about 2 % of windows
    colour_z: float = 2.0
    #: the innovation channels (:data:`CHANNELS`) whose colour sizes the evidence. The position
    #: channel is left out: an encoder's quantisation error stays constant while the piston
    #: rests, which colours it on the model's own recordings too (the thresholds were set on them)
    colour_channels: tuple = ("pA", "pB")

    def __post_init__(self):
        for name in ("held_p0_factor", "frozen_var", "start_step_s", "decision_window_s", "pair_window_s",
                     "min_single_fraction", "fit_nis"):
            if not _positive(getattr(self, name)):
                raise ValueError(f"BankDesign.{name} = {getattr(self, name)!r}: must be a finite number > 0")
        if not (_positive(self.colour_z) or self.colour_z == 0):
            raise ValueError(f"BankDesign.colour_z = {self.colour_z!r}: must be a number of standard deviations >= 0")
        for name in ("onset_lead_s", "min_evidence_s", "colour_lag_s"):
            v = getattr(self, name)
            if not (_positive(v) or v == 0):
                raise ValueError(f"BankDesign.{name} = {v!r}: must be a duration >= 0 s")
        for name in ("n_starts", "max_episodes"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"BankDesign.{name} = {v!r}: must be a whole number >= 1")
        for name in ("prior_sd", "min_pair_size"):
            table = getattr(self, name)
            if set(table) != set(FAULTS) or not all(map(_positive, table.values())):
                raise ValueError(f"BankDesign.{name} = {table!r}: must give a size > 0 (SI) for each of {FAULTS}")
        if not self.colour_channels or not set(self.colour_channels) <= set(CHANNELS):
            raise ValueError(f"BankDesign.colour_channels = {self.colour_channels!r}: must name some of {CHANNELS}")

    def colour(self, nu: np.ndarray, dt: float) -> np.ndarray:
        """(..., L) the evidence's variance inflation per sample of innovations ``nu`` (..., L, 3)
        sampled every ``dt`` [s] (:func:`fdi.whiteness.evidence_factor`)."""
        return evidence_factor(nu, int(round(self.colour_lag_s / dt)),
                               tuple(CHANNELS.index(c) for c in self.colour_channels), self.colour_z)

    @property
    def min_single_size(self) -> dict:
        """Smallest change (SI) of a single fault's parameter for the bank to name it."""
        return {k: self.min_single_fraction * v for k, v in self.min_pair_size.items()}


DESIGN = BankDesign()


def reference_config(design: BankDesign = None, sensors: Sensors | None = None,
                     form_noise: FormNoise | None = None) -> FilterConfig:
    """The healthy reference filter: the design's reference with every fault parameter held at
    its healthy value (no process noise, prior std x ``held_p0_factor``). ``sensors``: the
    detecting filter's, whose pressure, position and encoder noise the bank then assumes too (a
    recording's own noise, :func:`fdi.recording.recording_sensors`: a bank that expects quieter
    transmitters than the recording's would credit their noise to whichever fault absorbs most).
    ``form_noise``: the detecting filter's (:mod:`fdi.form_noise`), assumed too."""
    design = DESIGN if design is None else design
    base = design.reference if form_noise is None else design.reference.with_(form_noise=form_noise)
    if sensors is not None:
        base = base.with_(sensors=replace(base.sensors, pressure_noise=sensors.pressure_noise,
                                          x_noise=sensors.x_noise, theta_pulse=sensors.theta_pulse,
                                          theta_noise_floor=max(base.sensors.theta_noise_floor,
                                                                sensors.theta_noise_floor)))
    return (base.with_process_noise(**{f: 0.0 for f in FAULTS})
            .with_initial_sd(**{f: base.initial_sd[f] * design.held_p0_factor for f in FAULTS}))


def confirm_calibration(detect: FilterConfig, design: BankDesign = None) -> tuple:
    """The calibration states of ``detect`` that the confirmation bank keeps as uncertain
    constant states (``design.confirm_calibrate``)."""
    design = DESIGN if design is None else design
    return tuple(name for name in design.confirm_calibrate if name in detect.calibration.states)


def bank_config(detect: FilterConfig, kept: tuple = ()) -> FilterConfig:
    """The constrained filters: the reference filter's measurement model and model-state
    noise, its calibration states ``kept`` as uncertain CONSTANT states and the others' reference
    values written into the parameter vector (``kept`` = (): every one held), fault parameters
    constant (q = 0; the free one gets a prior), no divergence resets (a wrong hypothesis must
    keep its large innovations)."""
    const = {name: (p0, 0.0) for name, (p0, _) in detect.calibration.noise.items() if name in kept}
    return FilterConfig(
        process_noise={**detect.process_noise, **{f: 0.0 for f in FAULTS}},
        initial_sd=dict(detect.initial_sd), sigma_points=detect.sigma_points, sensors=detect.sensors,
        calibration=CalibrationStates(states=tuple(kept), walk=0.0, noise=const), unknown_inputs=UnknownInputStates(),
        constraints=Constraints(projection="leak"), guards=Guards(nis_factor=0.0), form_noise=detect.form_noise,
        stops=same_contact(StopRules(), detect.stops))


def same_contact(stops: StopRules, detect: StopRules) -> StopRules:
    """``stops`` with the end-stop contact of the detecting filter's ``detect``: every filter of a
    diagnosis steps the same model."""
    return replace(stops, contact_stiffness_N_per_m=detect.contact_stiffness_N_per_m,
                   contact_damping_ratio=detect.contact_damping_ratio)


def _rows(inp, rows: np.ndarray, k0: int, k1: np.ndarray, L: int):
    """The input of runs ``rows`` over [k0, k1) padded to L samples (input held, nothing
    measured after k1): a FilterInput-like dict of arrays (len(rows), L)."""
    n = len(rows)
    out = {}
    for name in ("u", "pA", "pB", "pos", "pS"):
        src = getattr(inp, name)
        if src is None:
            out[name] = None
            continue
        a = np.full((n, L), np.nan)
        for i, (b, ka, kb) in enumerate(zip(rows, k0, k1)):
            a[i, :kb - ka] = src[b, ka:kb]
            if name == "u":
                a[i, kb - ka:] = src[b, kb - 1]
        out[name] = a
    return out


def run_reference(out: FilterOutput, rows: np.ndarray, k_end: np.ndarray, design: BankDesign = None) -> FilterOutput:
    """The healthy reference filter of runs ``rows`` over [0, max k_end) (one batched call). It
    holds its calibration in long strokes where the detecting filter ``out`` does
    (FilterConfig.calib_hold_after_s): the bank starts from its calibration."""
    inp = out.inp
    L = int(max(1, np.max(k_end)))
    seg = _rows(inp, rows, np.zeros(len(rows), dtype=np.int64), np.minimum(k_end, inp.u.shape[1]), L)
    sub = replace(inp, params=inp.params[rows], **seg)
    base = reference_config(design, out.config.sensors, out.config.form_noise)
    cfg = base.with_(calibration=replace(base.calibration, hold_after_s=out.config.calibration.hold_after_s),
                     hold_band_V=out.config.hold_band_V, stops=same_contact(base.stops, out.config.stops))
    # the fault states are known constants here: no sigma points for them (29 instead of 37)
    held = np.zeros((len(rows), cfg.n_states), dtype=bool)
    held[:, list(FAULT_IDX)] = True
    return run_filter(sub, cfg, n_steps=np.minimum(k_end, inp.u.shape[1]), held=held)


def reference_rows(runs: np.ndarray, ref: FilterOutput, rows: np.ndarray) -> FilterOutput:
    """The rows of the reference ``ref`` (of runs ``runs``) that belong to runs ``rows``, in
    that order (each of ``rows`` must be in ``runs``)."""
    idx = np.array([int(np.flatnonzero(runs == b)[0]) for b in rows], dtype=np.int64)
    per_run = {f: getattr(ref, f)[idx] for f in ("mean", "std", "nu", "nis", "n_nan", "n_jitter", "n_cov_reset",
                                                 "n_state_reset", "u", "ll")}
    return replace(ref, **per_run)


@dataclass(frozen=True)
class BankResult:
    """Per run of the bank (n runs, H hypotheses, L samples from k0)."""

    k0: np.ndarray  #: (n,) start index of each run's bank in the recording
    loglik: np.ndarray  #: (n, H, L) cumulative innovation log-likelihood from k0 (scaled units)
    free: np.ndarray  #: (n, H, L) estimate of each hypothesis' (first) free parameter (SI; NaN for "none")
    free_sd: np.ndarray  #: (n, H, L)
    healthy: np.ndarray  #: (n, H) healthy value of each hypothesis' (first) free parameter (SI)
    n_valid: np.ndarray  #: (n,) samples inside each run's window
    names: tuple = tuple(BANK)  #: the hypotheses, in the order of axis 1 (per run: a list of tuples)
    #: (n, H, 4) change of each fault parameter (FAULT_IDX order, SI) at the window's last
    #: sample: the estimate minus its healthy value (0 for a held one)
    change: np.ndarray | None = None
    change_sd: np.ndarray | None = None  #: (n, H, 4) its filter std (SI)
    #: (n, H) recording sample at which each hypothesis' (best) filter started: its onset estimate
    start: np.ndarray | None = None
    #: (n, H, N_AUG + the bank's calibration states) scaled mean at the window's last sample
    z_last: np.ndarray | None = None
    var_last: np.ndarray | None = None  #: (n, H, ...) its scaled diagonal variances
    params: np.ndarray | None = None  #: (n, H, len(P)) parameter rows (reference calibration written in)
    z0: np.ndarray | None = None  #: (n, N_AUG + the bank's calibration states) scaled start mean
    var0: np.ndarray | None = None  #: (n, ...) its scaled diagonal variances
    nis: np.ndarray | None = None  #: (n, H) mean normalised innovation squared over the window (3 if consistent)
    #: (n, L, N_AUG + ...) scaled posterior mean and variances of the "none" filter (run_bank(keep_healthy=True))
    healthy_mean: np.ndarray | None = None
    healthy_var: np.ndarray | None = None
    #: (n, H, L) the variance inflation of each hypothesis' innovations from its start to each
    #: sample (:meth:`BankDesign.colour`): its evidence counts divided by it; None: 1
    colour: np.ndarray | None = None

    def hyps(self, i: int) -> tuple:
        """The hypothesis names of run i (axis 1 of the arrays)."""
        return self.names[i] if isinstance(self.names, list) else self.names

    def subset(self, idx) -> "BankResult":
        """The bank of runs ``idx`` only (every per-run array indexed on its first axis)."""
        idx = np.asarray(idx, dtype=np.int64)
        kw = {f: (v[idx] if isinstance(v, np.ndarray) else v) for f, v in vars(self).items()}
        if isinstance(self.names, list):
            kw["names"] = [self.names[i] for i in idx]
        return replace(self, **kw)


def run_bank(out: FilterOutput, ref: FilterOutput, rows: np.ndarray, k0: np.ndarray, k1: np.ndarray,
             hypotheses: tuple | list = tuple(BANK), ref_rows: np.ndarray | None = None,
             keep_healthy: bool = False, kept: tuple = (), design: BankDesign = None) -> BankResult:
    """The hypothesis bank of runs ``rows`` of the detection output ``out``, run i over
    samples [k0[i], k1[i]), seeded from row ``ref_rows[i]`` (default i) of the reference
    ``ref`` at k0[i]; ONE run_filter call for all runs and ``hypotheses``: names of BANK or
    PAIRS (:func:`free_states`), the same tuple for every run, or a list of one tuple per run
    (all of one length H). ``keep_healthy``: keep the "none" filter's trajectory. ``kept``: the
    reference's calibration states carried as uncertain constants (:func:`bank_config`)."""
    inp, det = out.inp, ref.config
    rows, k0, k1 = (np.asarray(a, dtype=np.int64) for a in (rows, k0, k1))
    ref_rows = np.arange(len(rows)) if ref_rows is None else np.asarray(ref_rows)
    n = len(rows)
    per_run = isinstance(hypotheses, list)
    names = [tuple(h) for h in hypotheses] if per_run else [tuple(hypotheses)] * n
    params, z0, var = seed_from(ref, inp, rows, k0, ref_rows, kept)
    return run_hypotheses(inp, bank_config(det, kept), rows, k0, k1, params, z0, var, names, per_run, keep_healthy,
                           design=design)


#: BankResult fields with one entry per run and hypothesis, taken from its most likely start.
_PER_HYPOTHESIS = ("healthy", "change", "change_sd", "start", "z_last", "var_last", "params", "nis")
#: BankResult fields (n, H, L) along the window, taken from a hypothesis' most likely start on
_ALONG = ("free", "free_sd", "colour")


def candidate_starts(k0: int, k_alarm: int, k1: int, dt: float, design: BankDesign = None) -> np.ndarray:
    """The bank's candidate onsets of one run: k0, k0 + step, ... (``n_starts`` at most, every
    ``start_step_s``), none after the alarm or at/after the window's end k1 (always k0 itself)."""
    design = DESIGN if design is None else design
    step = max(1, int(round(design.start_step_s / dt)))
    ks = k0 + step * np.arange(design.n_starts)
    return ks[(ks <= max(k0, min(k_alarm, k1 - 1)))]


def run_bank_starts(out: FilterOutput, ref: FilterOutput, rows: np.ndarray, k0: np.ndarray, k1: np.ndarray,
                    k_alarm: np.ndarray, hypotheses: tuple = tuple(BANK), ref_rows: np.ndarray | None = None,
                    kept: tuple = (), later_none: bool = True, design: BankDesign = None) -> BankResult:
    """The bank of :func:`run_bank` with the onset as a nuisance. Run i: the bank from k0[i]
    (seeded from the reference), and one bank from each later candidate onset tau of
    :func:`candidate_starts` seeded from that first bank's HEALTHY filter at tau (calibration
    held at the reference's values at k0, so that a fault between k0 and tau cannot be learnt
    as calibration, as the reference's random-walk calibration would); per hypothesis H the evidence averaged over the starts
    (equal prior):

        L_H(k) = log mean_tau exp(L_none(k0..tau) + L_H,tau(tau+1..k)),

    (for k <= tau the term is L_none(k0..k); the bank from tau is seeded with the healthy
    posterior at tau, so it counts from tau + 1). Two run_filter calls. ``later_none`` False:
    "none" runs from k0 only, its L_none(k0..k) for every start, for a bank whose "none" only
    seeds (the naming bank when a confirmation bank judges the alarm): a later start is seeded
    with the DIAGONAL of the healthy posterior, which alone moves "none" by tens of nats, so the
    evidence of a fault over "none" needs "none" restarted alike. Returned on the grid
    [k0[i], k1[i]) like run_bank's; each hypothesis' estimates, state and ``start`` come from
    its most likely start at the window's last sample."""
    dt = sample_step(out.t)
    rows, k0, k1, k_alarm = (np.asarray(a, dtype=np.int64) for a in (rows, k0, k1, k_alarm))
    names = tuple(hypotheses)
    first = run_bank(out, ref, rows, k0, k1, names, ref_rows=ref_rows, keep_healthy=True, kept=kept, design=design)
    later = [(i, int(tau)) for i in range(len(rows))
             for tau in candidate_starts(int(k0[i]), int(k_alarm[i]), int(k1[i]), dt, design)[1:]]
    if not later:
        return first
    owner = np.array([i for i, _ in later])
    taus = np.array([tau for _, tau in later])
    at = taus - k0[owner]
    z0 = first.healthy_mean[owner, at]
    var = first.healthy_var[owner, at]
    params = first.params[owner, 0]
    none = names.index("none")
    later = [h for h in range(len(names)) if later_none or h != none]  # the hypotheses run from later starts
    second = run_hypotheses(out.inp, bank_config(ref.config, kept), rows[owner], taus, k1[owner], params, z0, var,
                             [tuple(names[h] for h in later)] * len(owner), False, design=design)
    res = replace(first, loglik=first.loglik.copy(), **{f: getattr(first, f).copy() for f in _PER_HYPOTHESIS + _ALONG})
    for i in range(len(rows)):
        q = np.flatnonzero(owner == i)
        if not len(q):
            continue
        Li = int(k1[i] - k0[i])
        R = first.loglik[i, none, :Li]  # L_none(k0..k) at index k - k0
        E = np.empty((len(q) + 1, len(names), Li))
        E[:, none] = R  # where "none" is not run from the later starts
        E[0] = first.loglik[i, :, :Li]
        for s, qs in enumerate(q, start=1):
            off = int(at[qs])
            # the seed is the healthy posterior at tau, which has used y[tau]: the bank from tau
            # counts from tau + 1 (its own first term re-uses y[tau])
            E[s, later, :off + 1] = R[:off + 1]
            E[s, later, off + 1:] = R[off] + second.loglik[qs, :, 1:Li - off] - second.loglik[qs, :, :1]
        res.loglik[i, :, :Li] = np.logaddexp.reduce(E, axis=0) - math.log(len(E))
        res.loglik[i, :, Li:] = res.loglik[i, :, Li - 1:Li]
        for h, s in enumerate(np.argmax(E[:, :, Li - 1], axis=0)):  # most likely start per hypothesis
            if s == 0 or h not in later:
                continue
            qs, g = q[s - 1], later.index(h)
            off = int(at[qs])
            for f in _ALONG:
                along = getattr(res, f)
                along[i, h, :off] = np.nan if f != "colour" else 1.0
                along[i, h, off:Li] = getattr(second, f)[qs, g, :Li - off]
            for f in _PER_HYPOTHESIS:
                getattr(res, f)[i, h] = getattr(second, f)[qs, g]
    return res


def start_seed(bank: BankResult, q: int, k: int) -> tuple:
    """(params, z0, var) of a bank filter of run q of ``bank`` started at sample k: the bank's
    own seed at its k0, else its healthy filter's posterior at k (as :func:`run_bank_starts`
    seeds its later starts)."""
    if k == bank.k0[q]:
        return bank.params[q, 0], bank.z0[q], bank.var0[q]
    return bank.params[q, 0], bank.healthy_mean[q, k - bank.k0[q]], bank.healthy_var[q, k - bank.k0[q]]


def seed_from(ref: FilterOutput, inp, rows: np.ndarray, k0: np.ndarray, ref_rows: np.ndarray,
              kept: tuple = ()):
    """Start of bank filters from row ref_rows[i] of ``ref`` at sample k0[i]: the parameter rows
    (n, len(P)) of runs ``rows`` with ref's calibration values written in (but those ``kept`` as
    states, :func:`bank_config`), and the scaled means and diagonal variances (n, N_AUG +
    len(kept)) of its first N_AUG states and the kept ones."""
    cols, rel = ref.config.param_layout()
    calibrated = ref.config.calibration.states
    idx = np.r_[np.arange(N_AUG), [N_AUG + calibrated.index(c) for c in kept]].astype(np.int64)
    sc = ref.config.state_scale()[idx]
    n = len(rows)
    params = np.empty((n, inp.params.shape[1]))
    z0 = np.empty((n, len(idx)))
    var = np.empty((n, len(idx)))
    for i, (b, ka) in enumerate(zip(rows, k0)):
        mean = ref.mean[ref_rows[i], ka]
        params[i] = inp.params[b]
        for a in range(len(cols)):  # calibration states -> the parameter vector
            if rel[a] and calibrated[a - (N_AUG - N_MODEL)] not in kept:
                params[i, cols[a]] = inp.params[b, cols[a]] * (1.0 + max(mean[N_MODEL + a], -0.95))
        z0[i] = mean[idx] / sc
        var[i] = (ref.std[ref_rows[i], ka, idx] / sc) ** 2
    return params, z0, var


def run_hypotheses(inp, cfg: FilterConfig, rows, k0, k1, params, z0, var, names: list, per_run: bool,
                    keep_healthy: bool = False, design: BankDesign = None) -> BankResult:
    """The filters ``cfg`` of runs ``rows`` over [k0, k1): run i starts from the scaled mean
    z0[i] (n_states,) and diagonal variances var[i], its parameter row params[i]; in hypothesis
    names[i][h] the fault states are held (known constants, ``run_filter(held=...)``; their
    reported variance ``frozen_var``) except the free ones, whose variance gets ``prior_sd``^2 added.
    ONE run_filter call (B = runs x hypotheses). ``keep_healthy``: also keep the "none"
    hypothesis' scaled mean and variances over the window (healthy_mean, healthy_var)."""
    design = DESIGN if design is None else design
    n, H = len(rows), len(names[0])
    ns = z0.shape[1]
    frees = [[free_states(h) for h in nm] for nm in names]  # (n, H) tuples of state indices
    L = int(max(1, (k1 - k0).max()))
    sc = cfg.state_scale()
    seg = _rows(inp, rows, k0, k1, L)
    P0 = np.zeros((n, H, ns, ns))
    held = np.zeros((n, H, ns), dtype=bool)  # the fault states not free: known constants
    for i in range(n):
        for h, free in enumerate(frees[i]):
            d = var[i].copy()
            d[list(FAULT_IDX)] = design.frozen_var
            held[i, h, [j for j in FAULT_IDX if j not in free]] = True
            for j in free:
                d[j] += (design.prior_sd[STATE_NAMES[j]] / SCALE[j]) ** 2
            P0[i, h] = np.diag(d)
    rep = lambda a: None if a is None else np.repeat(a, H, axis=0)  # noqa: E731  run-major, hypothesis-minor
    bank_inp = replace(inp, **{k: rep(v) for k, v in seg.items()}, params=rep(params))
    res = run_filter(bank_inp, cfg, z0=rep(z0), P0=P0.reshape(n * H, ns, ns),
                     n_steps=rep(k1 - k0), held=held.reshape(n * H, ns))  # each run only over its own window
    loglik = np.cumsum(np.nan_to_num(res.ll), axis=1).reshape(n, H, L)
    nis = np.nanmean(np.nansum(res.nu ** 2, axis=2) + np.where(np.isnan(res.ll), np.nan, 0.0), axis=1).reshape(n, H)
    mean = res.mean.reshape(n, H, L, -1)
    std = res.std.reshape(n, H, L, -1)
    free_est = np.full((n, H, L), np.nan)
    free_sd = np.full((n, H, L), np.nan)
    healthy = np.full((n, H), np.nan)
    last = np.clip(k1 - k0 - 1, 0, L - 1)
    fi = list(FAULT_IDX)
    z_last = mean[np.arange(n), :, last] / sc  # (n, H, n_states) scaled
    v_last = (std[np.arange(n), :, last] / sc) ** 2
    change = z_last[:, :, fi] * sc[fi] - (z0[:, fi] * sc[fi])[:, None, :]
    change_sd = np.sqrt(v_last[:, :, fi]) * sc[fi]
    for i in range(n):
        for h, free in enumerate(frees[i]):
            if free:
                j = free[0]
                free_est[i, h], free_sd[i, h] = mean[i, h, :, j], std[i, h, :, j]
                healthy[i, h] = z0[i, j] * sc[j]
    kept_none = {}
    if keep_healthy:
        h = names[0].index("none")
        kept_none = {"healthy_mean": mean[:, h] / sc, "healthy_var": (std[:, h] / sc) ** 2}
    colour = design.colour(res.nu, inp.dt).reshape(n, H, L)
    return BankResult(k0=k0, loglik=loglik, free=free_est, free_sd=free_sd, healthy=healthy, n_valid=k1 - k0,
                      names=names if per_run else names[0], change=change, change_sd=change_sd, colour=colour,
                      start=np.repeat(k0[:, None], H, axis=1), z_last=z_last, var_last=v_last,
                      params=np.repeat(params[:, None], H, axis=1), z0=z0, var0=var, nis=nis, **kept_none)


def run_pairs(out: FilterOutput, ref: FilterOutput, first: BankResult, rows: np.ndarray, k1: np.ndarray,
              best: list, design: BankDesign = None) -> BankResult:
    """Several-faults stage of runs ``rows``: every single fault and every pair (:data:`MULTI`)
    over [first's window end, k1[i]), each run restarted from the filter of its best single
    fault best[i] in the stage-1 bank ``first`` at that bank's last sample (model states:
    mean and variances; the parameter row with the reference's calibration) with EVERY fault
    parameter back at its healthy value and the free ones given their prior again. The restart
    is what makes the comparison fair: a filter started before the onset has learnt
    "no fault" from the healthy samples and then needs a second parameter to follow the step,
    which a pair has (docs/fdi-design.md, "Several faults"). ONE run_filter call (B = runs x 10)."""
    hs = [first.hyps(i).index(b) for i, b in enumerate(best)]
    ks = first.k0 + first.n_valid
    z0 = np.stack([first.z_last[i, h] for i, h in enumerate(hs)])
    var = np.stack([first.var_last[i, h] for i, h in enumerate(hs)])
    params = np.stack([first.params[i, h] for i, h in enumerate(hs)])
    z0[:, list(FAULT_IDX)] = first.z0[:, list(FAULT_IDX)]  # leaks and offset restart at healthy
    return run_hypotheses(out.inp, bank_config(ref.config), rows, ks, np.maximum(k1, ks + 1), params, z0,
                           var, [MULTI] * len(rows), False, design=design)


def calibrated_seed(ref: FilterOutput, ref_rows: np.ndarray, k: np.ndarray) -> tuple:
    """Start of :func:`pair_config` filters from row ref_rows[i] of the reference ``ref`` at
    sample k[i]: scaled means and diagonal variances (n, N_AUG + its calibration states)."""
    nc = len(ref.config.calibration.states)
    sc = pair_config(ref.config).state_scale()
    z0 = np.stack([ref.mean[r, int(ki), :N_AUG + nc] for r, ki in zip(ref_rows, k)]) / sc
    var = (np.stack([ref.std[r, int(ki), :N_AUG + nc] for r, ki in zip(ref_rows, k)]) / sc) ** 2
    return z0, var


def run_bank_calibrated(out: FilterOutput, ref: FilterOutput, rows: np.ndarray, k0: np.ndarray,
                        k1: np.ndarray, hypotheses: tuple = tuple(BANK), design: BankDesign = None) -> BankResult:
    """The bank of :func:`run_bank`, but with the reference's calibration as uncertain constant
    states (:func:`pair_config`) instead of values written into the parameter vector: run i
    over [k0[i], k1[i]), seeded from row i of ``ref`` at k0[i]. ONE run_filter call."""
    rows = np.asarray(rows, dtype=np.int64)
    z0, var = calibrated_seed(ref, np.arange(len(rows)), k0)
    return run_hypotheses(out.inp, pair_config(ref.config), rows, np.asarray(k0), np.asarray(k1),
                           out.inp.params[rows], z0, var, [tuple(hypotheses)] * len(rows), False, design=design)


def pair_config(detect: FilterConfig) -> FilterConfig:
    """The bank's filters (:func:`bank_config`) with every calibration state of ``detect`` as an
    uncertain CONSTANT state (no random walk), started from the reference's values and
    variances: what the bound of :mod:`fdi.bound` runs."""
    bank = bank_config(detect)
    const = {name: (p0, 0.0) for name, (p0, _) in detect.calibration.noise.items()}
    return bank.with_(calibration=replace(bank.calibration, states=detect.calibration.states, noise=const))


