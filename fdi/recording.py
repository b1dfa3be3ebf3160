"""The first stage: a recording, checked, becomes the filter's input.

Only a recording's measured columns are ever used (:meth:`sam.Recording.measured`). A sample
outside what the sensors or the plant's stroke allow is refused in one line (or, on request,
made a missing sample); a recording too short, too coarse or sampled at another rate than its
thresholds is refused with what to do; a plant file under which a fault could not show is refused.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sam import P, Plant, Recording, UserError, initial_state, simulate_batch, stroke_ends, white_noise_std
from sam.geometry import joint_angle, piston_position
from sam.measurement import ENCODER_RESOLUTION_RAD

from .config import Sensors, StopRules
from .filter import FilterInput, model_substeps
from .states import K_PER_LPM, POS_THETA, POS_X
from .thresholds import Thresholds


@dataclass(frozen=True)
class InputChecks:
    """What a recording must satisfy before the filter sees it."""

    pressure_range_Pa: tuple = (0.0, 25e6)  #: the SAM's pressure sensors
    range_margin_Pa: float = 0.5e6  #: noise around the range's ends that is still accepted
    #: Pa: a chamber pressure read within this of the range's lower end is missing to the filter: a
    #: transmitter clips there (a cavitating chamber at -0.1 MPa reads 0), so such a reading says
    #: only "at or below", while the model's chamber goes to the vapour pressure
    floor_band_Pa: float = 50e3
    #: m: how far a position may stray outside the plant's stroke (sensor zero and noise); further
    #: out the recording and the plant file describe different machines
    position_margin_m: float = 0.005
    #: Hz: the coarsest sampling accepted; detection fades with the rate (thresholds derived for it
    #: keep the false alarms at their level) and below this nothing is left
    min_sample_rate_Hz: float = 100.0
    rate_tolerance: float = 0.01  #: relative: a recording's step against its thresholds' (1 % clock jitter)
    #: pulses of theta per window in which an x's phases on the encoder grid are summed
    #: (:func:`encoder_grid_coherence`): local, so that a slightly wrong geometry keeps the grid
    encoder_grid_window: int = 50
    #: an x with at least this coherence was computed from the encoder (1 on the grid, about
    #: 1 / sqrt(samples per window) for a continuous reading)
    encoder_grid_coherence: float = 0.6
    #: Pa: a fault of a clear size (1 L/min at 10 MPa, 2 %) must move the chamber pressures by more
    #: than this (the sensor noise) under the recording's input, or the plant is refused
    observable_Pa: float = 20e3
    observability_s: float = 2.0  #: s: of the recording's input simulated for that check
    #: V: a valve input whose range is below this is constant: one operating point, which cannot
    #: tell the faults apart (K_int and the offset act alike there) nor show that the model fits
    min_input_range_V: float = 0.05
    #: the filter takes a recording's own sensor noise (:func:`recording_sensors`) where it is
    #: above the configured one by more than this factor; below, the configured one stands (the
    #: thresholds' false-alarm level was set with it); None: always the configured noise
    own_noise_factor: float | None = 1.25
    #: an encoder's steps between samples are whole numbers of its pulse: at least this share of
    #: them within ``grid_tolerance`` pulses of one (:func:`encoder_pulse`) for a grid of any pulse
    grid_share: float = 0.9
    grid_tolerance: float = 0.1


CHECKS = InputChecks()


@dataclass(frozen=True)
class InputReport:
    """What the checks found in a recording (part of diagnosis.json's filter_health)."""

    samples: int
    dt_s: float
    position: str  #: the position column filtered: "x" or "theta"
    supply_pressure_measured: bool
    out_of_range_samples: int  #: samples made missing by --drop-out-of-range
    ignored_optional_columns: list
    u_gaps_held: int = 0  #: missing input samples held at the last value
    pressure_noise_Pa: float = float("nan")  #: the transmitters' own white noise (:func:`white_noise_std`)
    encoder_pulse_rad: float = float("nan")  #: the encoder's pulse found in the data (:func:`encoder_pulse`)
    at_range_floor_samples: int = 0  #: chamber-pressure readings at the transmitter's floor, made missing

    def to_dict(self) -> dict:
        d = {"samples": self.samples, "dt_s": self.dt_s, "position": self.position,
             "supply_pressure_measured": self.supply_pressure_measured,
             "out_of_range_samples": self.out_of_range_samples, "ignored_optional_columns": self.ignored_optional_columns}
        if self.u_gaps_held:
            d["u_gaps_held"] = self.u_gaps_held
        if self.at_range_floor_samples:
            d["at_range_floor_samples"] = self.at_range_floor_samples
        if np.isfinite(self.pressure_noise_Pa):
            d["pressure_noise_Pa"] = round(float(self.pressure_noise_Pa), 1)
        if np.isfinite(self.encoder_pulse_rad):
            d["encoder_pulse_deg"] = float(f"{np.rad2deg(self.encoder_pulse_rad):.4g}")
        return d


def encoder_pulse(theta: np.ndarray, checks: InputChecks = CHECKS) -> float:
    """rad: the pulse of the encoder that read the joint angles ``theta`` (T,), found in the data;
    nan for angles that are not on a grid (a continuous sensor) or that hardly move. Between
    samples an encoder steps by whole pulses: the smallest steps are one pulse, and at least
    ``grid_share`` of all steps lie within ``grid_tolerance`` pulses of a whole number of it."""
    steps = np.abs(np.diff(np.asarray(theta, dtype=float)[np.isfinite(theta)]))
    steps = steps[steps > 0]
    if len(steps) < 20:
        return float("nan")
    one = steps[steps < 1.5 * steps.min()]
    pulse = float(np.median(one))
    k = steps / pulse
    on_grid = np.mean(np.abs(k - np.round(k)) < checks.grid_tolerance)
    return pulse if on_grid >= checks.grid_share and len(one) >= 0.05 * len(steps) else float("nan")


def _angles(inp_pos: np.ndarray, pos_kind: int, params: np.ndarray) -> np.ndarray:
    """Joint angles [rad] of a position record (theta as it is; x through the plant's Eq. (3))."""
    if pos_kind == POS_THETA:
        return inp_pos
    return joint_angle(inp_pos, params[P.L_1], params[P.L_2], params[P.L_3])


def recording_sensors(sensors: Sensors, inp: FilterInput, checks: InputChecks = CHECKS) -> Sensors:
    """The sensor noise the filter assumes for this recording: ``sensors`` (the configured one),
    with the pressure noise (the larger of pA's and pB's :func:`white_noise_std`), a linear
    transducer's noise, and an encoder's pulse (:func:`encoder_pulse`; for an x computed from
    it, that pulse and the angle's noise floor carried into x) raised to the recording's own
    where that is above the configured one by more than ``checks.own_noise_factor``. Never
    lowered: a filter that trusted quieter sensors than the thresholds were derived with would
    alarm more often."""
    factor = checks.own_noise_factor
    if factor is None:
        return sensors
    own_p = np.fmax(white_noise_std(inp.pA[0]), white_noise_std(inp.pB[0]))
    if own_p > factor * sensors.pressure_noise:
        sensors = replace(sensors, pressure_noise=own_p)
    own_x = white_noise_std(inp.pos[0]) if inp.linear_position else float("nan")
    if own_x > factor * sensors.x_noise:
        sensors = replace(sensors, x_noise=own_x)
    pulse = encoder_pulse(_angles(inp.pos[0], inp.pos_kind, inp.params[0]), checks)
    if not pulse > factor * sensors.theta_pulse:
        return sensors
    # a coarser encoder: its rounding error, constant while the arm is slow or held, grows with
    # its pulse, and so does the floor that stands for it (Sensors.theta_noise_floor)
    coarse = replace(sensors, theta_pulse=pulse,
                     theta_noise_floor=sensors.theta_noise_floor * pulse / sensors.theta_pulse)
    if inp.pos_kind == POS_THETA:
        return coarse
    # x computed from it: the same, in x
    steps = np.abs(np.diff(inp.pos[0]))
    theta_steps = np.abs(np.diff(_angles(inp.pos[0], POS_X, inp.params[0])))
    one = (theta_steps > 0.5 * pulse) & (theta_steps < 1.5 * pulse)
    dx_dtheta = float(np.median(steps[one] / theta_steps[one])) if one.any() else 0.0
    own_x = dx_dtheta * np.hypot(pulse / np.sqrt(12.0), coarse.theta_noise_floor)
    return replace(coarse, x_noise=float(np.fmax(own_x, sensors.x_noise)))


def encoder_grid_coherence(x: np.ndarray, plant: Plant, checks: InputChecks = CHECKS) -> float:
    """How closely positions x (T,) [m], turned back into joint angles with the plant's geometry,
    sit on the encoder's grid of pulses, 0-1: the mean resultant length of their phases on the
    grid, summed over windows of ``encoder_grid_window`` pulses; 0 when no sample maps to an angle."""
    p = plant.vector()
    x = np.asarray(x, dtype=float)
    theta = joint_angle(x[np.isfinite(x)], p[P.L_1], p[P.L_2], p[P.L_3])
    phase = theta[np.isfinite(theta)] / ENCODER_RESOLUTION_RAD  # in pulses
    if not len(phase):
        return 0.0
    _, window = np.unique(np.floor(phase / checks.encoder_grid_window), return_inverse=True)
    z = np.exp(2j * np.pi * phase)
    resultant = np.bincount(window, z.real) + 1j * np.bincount(window, z.imag)
    return float(np.abs(resultant).sum() / len(phase))


def detect_position_sensor(rec: Recording, plant: Plant, checks: InputChecks = CHECKS) -> str:
    """The position sensor of a recording (fdi.thresholds.SHIPPED_BY_SENSOR): "encoder" for theta
    or an x computed from an encoder's theta (on the SAM encoder's grid, or on a grid of any
    pulse :func:`encoder_pulse` finds), "linear" for any other x. The
    thresholds depend on it, and so does the filter on an end stop. An x that never moves reads
    as the encoder."""
    if "x" not in rec.signals:
        return "encoder"
    x = rec.signals["x"]
    coherent = encoder_grid_coherence(x, plant, checks) >= checks.encoder_grid_coherence
    return "encoder" if coherent or np.isfinite(encoder_pulse(_angles(x, POS_X, plant.vector()), checks)) else "linear"


def filter_input(rec: Recording, plant: Plant, *, drop_out_of_range: bool = False,
                 position_sensor: str | None = None, checks: InputChecks = CHECKS,
                 stops: StopRules = StopRules()) -> tuple[FilterInput, InputReport]:
    """Check a (measured-only) recording and turn it into the filter's input. ``position_sensor``:
    where its x came from (:func:`detect_position_sensor` when None); ``stops``: the filter's
    stop rules (a model with rigid stops reads positions beyond one as the stop, :func:`at_the_stops`)."""
    name = str(rec.source) if rec.source else "recording"
    if rec.n < 10:
        raise UserError(f"{name}: only {rec.n} samples; the filter needs at least 10")
    sig = {k: np.array(v, dtype=float) for k, v in rec.signals.items()}
    dropped = 0
    lo, hi = checks.pressure_range_Pa
    for ch in ("pA", "pB", "pS"):
        if ch in sig:
            a = sig[ch]
            bad = np.isfinite(a) & ((a < lo - checks.range_margin_Pa) | (a > hi + checks.range_margin_Pa))
            dropped += _drop(name, rec.t, ch, a, bad, "Pa", f"the sensor range {lo / 1e6:g}-{hi / 1e6:g} MPa",
                             drop_out_of_range)
    floored = 0
    for ch in ("pA", "pB"):
        with np.errstate(invalid="ignore"):
            at_floor = sig[ch] <= lo + checks.floor_band_Pa
        floored += int(at_floor.sum())
        sig[ch][at_floor] = np.nan
    column = "x" if "x" in sig else "theta"
    bad, stroke = _outside_stroke(column, sig[column], plant, checks.position_margin_m)
    dropped += _drop(name, rec.t, column, sig[column], bad, "m" if column == "x" else "rad", stroke,
                     drop_out_of_range, hint="check the sensor's zero and sign, or the plant file; ")
    for ch in ("pA", "pB", column):
        if not np.isfinite(sig[ch]).any():  # --drop-out-of-range left nothing of it
            raise UserError(f"{name}: '{ch}': every sample is outside its valid range; nothing is left to filter")
    if "pS" in sig and not np.isfinite(sig["pS"]).any():  # the plant's supply pressure, as without the column
        del sig["pS"]
    u, gaps = sig["u"], int(np.isnan(sig["u"]).sum())
    if gaps:  # the input drives the model: hold the last value through a gap
        idx = np.where(np.isfinite(u), np.arange(len(u)), 0)
        np.maximum.accumulate(idx, out=idx)
        u = u[idx]
        u[~np.isfinite(u)] = 0.0
    sensor = "encoder" if column == "theta" else position_sensor or detect_position_sensor(rec, plant, checks)
    inp = FilterInput(dt=rec.dt, u=u[None, :], pA=sig["pA"][None, :], pB=sig["pB"][None, :],
                      pos=(at_the_stops(column, sig[column], plant) if rigid_stops(plant, stops)
                           else sig[column])[None, :],
                      pos_kind=POS_X if column == "x" else POS_THETA, params=plant.vector()[None, :],
                      pS=sig["pS"][None, :] if "pS" in sig else None, position_sensor=sensor)
    return inp, InputReport(samples=rec.n, dt_s=rec.dt, position=column, supply_pressure_measured="pS" in sig,
                            out_of_range_samples=dropped, at_range_floor_samples=floored,
                            ignored_optional_columns=sorted(set(rec.signals) & {"v", "xs"}), u_gaps_held=gaps,
                            pressure_noise_Pa=float(np.fmax(white_noise_std(sig["pA"]), white_noise_std(sig["pB"]))),
                            encoder_pulse_rad=encoder_pulse(_angles(inp.pos[0], inp.pos_kind, inp.params[0]), checks)
                            if sensor == "encoder" else float("nan"))


def _drop(name: str, t, column: str, a: np.ndarray, bad: np.ndarray, unit: str, valid: str, drop: bool,
          hint: str = "") -> int:
    """Samples ``bad`` of column ``a`` lie outside ``valid``: refuse the recording (UserError) or,
    with ``drop`` (--drop-out-of-range), make them missing (NaN, in place); returns how many."""
    if not bad.any():
        return 0
    i = int(np.flatnonzero(bad)[0])
    if not drop:
        raise UserError(f"{name}: '{column}': {int(bad.sum())} sample(s) outside {valid} (first at data row "
                        f"{i + 1}, t = {t[i]:.6g} s: {a[i]:.6g} {unit}); {hint}use --drop-out-of-range to treat "
                        "them as missing samples")
    a[bad] = np.nan
    return int(bad.sum())


def rigid_stops(plant: Plant, stops: StopRules) -> bool:
    """Whether the filter's model stops the piston dead at the end stops: the plant's are rigid
    and the filter's ``stops`` draw no contact (:meth:`fdi.config.StopRules.model_params`)."""
    return plant.stops.k_stop == 0.0 and stops.contact_stiffness_N_per_m == 0.0


def at_the_stops(column: str, pos: np.ndarray, plant: Plant) -> np.ndarray:
    """The position column ("x" [m] or "theta" [rad]) with readings beyond an end stop (within
    the accepted margin) moved onto the stop, for a model whose stops are rigid and inelastic:
    its piston cannot be beyond one, but a machine's stop gives under its load, and an encoder's
    zero is off by a part of a count: such a reading held on a stop would pull every state that
    moves the piston (docs/fdi.md, "On rig recordings"). A model with an elastic stop takes the
    reading as it is: its piston enters the contact as the machine's does."""
    p = plant.vector()
    L = p[P.L_1], p[P.L_2], p[P.L_3]
    x_end = float(stroke_ends(p))
    ends = (0.0, x_end) if column == "x" else tuple(sorted((joint_angle(0.0, *L), joint_angle(x_end, *L))))
    with np.errstate(invalid="ignore"):  # NaN (missing) stays missing
        return np.where(np.isfinite(pos), np.clip(pos, *ends), pos)


def _outside_stroke(column: str, pos: np.ndarray, plant: Plant, margin: float) -> tuple[np.ndarray, str]:
    """(bad (T,), description): samples of the position column ("x" [m] or "theta" [rad]) whose
    piston position lies outside the plant's stroke [0, x_end] by more than ``margin`` [m] (theta
    outside (0, pi) has no position): there the filter would hold the piston on an end stop at
    every sample and report a confident, meaningless diagnosis."""
    p = plant.vector()
    L = p[P.L_1], p[P.L_2], p[P.L_3]
    x_end = float(stroke_ends(p))
    if column == "x":
        x = pos
    else:
        x = np.where((pos > 0.0) & (pos < np.pi), piston_position(np.clip(pos, 0.0, np.pi), *L), np.nan)
    bad = np.isfinite(pos) & ~((x >= -margin) & (x <= x_end + margin))
    ends = ("" if column == "x" else
            f"theta {joint_angle(0.0, *L):.4g}-{joint_angle(x_end, *L):.4g} rad, i.e. ") + f"x 0-{x_end:.4g} m"
    limit = (f"theta_max {p[P.theta_max]:g} rad limits x_max {p[P.x_max]:g} m" if x_end < p[P.x_max]
             else f"x_max {p[P.x_max]:g} m")
    return bad, f"the plant's stroke ({ends}, +-{margin * 1e3:g} mm; {limit})"


def check_observable(inp: FilterInput, plant: Plant, name: str = "plant", recording: str = "the recording",
                     checks: InputChecks = CHECKS) -> None:
    """Refuse a plant under which a fault parameter cannot change the measurements: the
    recording's input simulated with each fault at a clear size (1 L/min at 10 MPa, 2 % offset)
    must move the chamber pressures by more than ``observable_Pa`` or the recording's own
    pressure noise (:func:`white_noise_std`), whichever is larger."""
    T = min(inp.u.shape[1], int(checks.observability_s / inp.dt) + 1)
    p0 = plant.vector()
    rows = [p0.copy()]
    sizes = {"K_int": K_PER_LPM, "K_extA": K_PER_LPM, "K_extB": K_PER_LPM, "offset": 0.02}
    for f, v in sizes.items():
        p = p0.copy()
        p[P[f]] = v
        rows.append(p)
    params = np.array(rows)
    x0 = initial_state(params, x=0.05)
    n_sub = model_substeps(inp.dt)  # the model steps the filter takes: a coarse recording's input held
    res = simulate_batch(params, np.repeat(inp.u[0, :T - 1], n_sub), inp.dt / n_sub, x0=x0,
                         record_every=n_sub, channels=("p_A", "p_B", "x"))
    if not all(np.isfinite(res[c]).all() for c in ("p_A", "p_B", "x")):
        raise UserError(f"{name}: the model diverges under this plant and the input of {recording}; "
                        "check the plant parameters (lengths and diameters in m, volumes, B_eff, valve flows)")
    own = max(white_noise_std(inp.pA[0]), white_noise_std(inp.pB[0]))
    noise = max(checks.observable_Pa, own) if np.isfinite(own) else checks.observable_Pa
    for i, f in enumerate(sizes, start=1):
        effect = max(np.max(np.abs(res["p_A"][i] - res["p_A"][0])), np.max(np.abs(res["p_B"][i] - res["p_B"][0])))
        if not effect > noise:
            raise UserError(
                f"{name}: parameter '{f}' is unobservable with this plant: a fault of "
                f"{'2 %' if f == 'offset' else '1 L/min at 10 MPa'} changes the chamber pressures by "
                f"only {effect:.3g} Pa (< the {noise / 1e3:.3g} kPa sensor noise) under the input of "
                f"{recording}; check p_S, B_eff, V_0A, V_0B and the valve flows")


def decimation(rec: Recording, dt_s: float, checks: InputChecks = CHECKS) -> int | None:
    """k when ``rec`` is sampled k whole times faster than every ``dt_s`` (k = 1: at that rate,
    within ``rate_tolerance``), None when it is not."""
    ratio = dt_s / rec.dt
    k = max(1, round(ratio))
    return k if abs(ratio / k - 1.0) <= checks.rate_tolerance else None


def study_rate(rec: Recording, checks: InputChecks = CHECKS) -> float | None:
    """The rate below 1000 Hz that ``samfdi fdi thresholds --sample-rate`` can derive thresholds
    for and ``rec`` is sampled at, None when there is none (the studies sample every whole ms)."""
    rate = 1.0 / rec.dt
    supported = 1000.0 / max(1, round(rec.dt * 1e3))
    ok = rate < 1000.0 and abs(supported / rate - 1.0) <= checks.rate_tolerance and supported >= checks.min_sample_rate_Hz
    return supported if ok else None


def at_thresholds_rate(rec: Recording, th: Thresholds, checks: InputChecks = CHECKS) -> tuple[Recording, int]:
    """The recording at the rate its thresholds were derived for (sigma and h depend on it), and
    the decimation k: as it is (k = 1) within ``rate_tolerance`` of that rate, every k-th sample
    when it is a whole k times faster; otherwise a UserError that names what to do."""
    min_rate = checks.min_sample_rate_Hz
    if not (rec.dt <= (1.0 + checks.rate_tolerance) / min_rate):
        raise UserError(f"{rec.source or 'recording'}: 't': sampled every {rec.dt * 1e3:.3g} ms ({1 / rec.dt:.4g} Hz); "
                        f"the filter needs {min_rate:g} Hz or faster to follow the chamber pressures")
    k = decimation(rec, th.derived.sample_dt_s, checks)
    if k == 1:
        return rec, 1
    if k is not None:
        return Recording(rec.t[::k], {c: v[::k] for c, v in rec.signals.items()}, {}, rec.metadata, rec.source), k
    supported = study_rate(rec, checks)
    if supported is not None:
        todo = (f"derive thresholds for it with `samfdi fdi thresholds --sample-rate {supported:.5g} --out DIR` "
                "and pass --thresholds DIR/thresholds.toml")
    else:
        todo = "resample it to 1000 Hz, or to 1000 / k Hz (k = 2 ... 10) and derive thresholds for that rate"
    raise UserError(f"{rec.source or 'recording'}: 't': sampled at {1 / rec.dt:.4g} Hz, but the thresholds are "
                    f"for {1 / th.derived.sample_dt_s:.4g} Hz; {todo}")


def excitation_caveat(inp: FilterInput, checks: InputChecks = CHECKS) -> str:
    """Words saying that the recording's valve input is constant (its range below
    ``min_input_range_V``), so that it cannot support a diagnosis; '' when it varies."""
    u = inp.u[0]
    if np.ptp(u) >= checks.min_input_range_V:
        return ""
    return (f"the valve input u is constant ({np.mean(u):.3g} V throughout, range {np.ptp(u):.2g} V < "
            f"{checks.min_input_range_V:g} V): one operating point cannot tell the faults apart; record the "
            "machine with the valve driven in both directions")


def check_duration(rec: Recording, th: Thresholds, own_baseline: bool, role: str = "") -> None:
    """Refuse a recording too short to test, or whose input, pressures or position were measured
    for less than that time (the rest missing): "healthy" would only mean "not looked at".
    ``role``: the option that gave the recording ("--reference"), for the message."""
    w = th.window
    needed = w.warmup_s + (w.baseline_s if own_baseline else 0.0) + w.min_tested_s
    parts = f"{w.warmup_s:g} s filter warm-up" + (f", {w.baseline_s:g} s healthy baseline" if own_baseline else "")
    need = f"a diagnosis needs at least {needed:g} s ({parts} and {w.min_tested_s:g} s to test)"
    name = f"{rec.source or 'recording'}: " + (f"{role}: " if role else "")
    duration = float(rec.t[-1] - rec.t[0])
    if duration < needed:
        raise UserError(f"{name}'t': only {duration:.3g} s long; {need}")
    for column in ("u", "pA", "pB", "x" if "x" in rec.signals else "theta"):
        measured = int(np.isfinite(rec.signals[column]).sum())
        if measured * rec.dt < needed:  # NaN samples are predicted through, but not a whole diagnosis
            raise UserError(f"{name}'{column}': only {measured} of {rec.n} samples ({measured * rec.dt:.3g} s) are "
                            f"numbers, the rest missing (NaN); {need}")
