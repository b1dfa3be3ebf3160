"""Turn a recording into what the diagnosis needs, refusing what it cannot use.

Everything the user can get wrong about the *data* is checked here and raised
as one-line :class:`sam.errors.UserError` messages: missing columns, a recording
too short to separate hypotheses, an input that does not excite the system, a
validation file from another plant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from sam import P, Plant, S, simulate_batch
from sam.errors import UserError
from sam.geometry import piston_position, stroke_end
from sam.measurement import at_ceiling
from sam.recording import Recording

from .settings import Settings

#: Shortest recording the diagnosis accepts [s]: it needs at least three
#: simulation segments, two to fit and one to hold out.
MIN_DURATION_S = 3.0
#: Smallest peak-to-peak control signal [V] that counts as an excitation.
MIN_INPUT_RANGE_V = 0.05
#: Shortest simulation segment [s]: each segment starts with a 30 ms start-up transient that is not
#: scored (SegmentSimulator's skip_s), and a segment ten times as long is mostly scored dynamics.
MIN_SEGMENT_S = 0.3


@dataclass
class Prepared:
    """A recording as arrays on its sample grid, with smoothed states and the spool trajectory."""

    name: str
    t: np.ndarray
    dt: float  # sample step [s]
    n_sub: int  # simulation sub-steps per sample
    u: np.ndarray
    y: dict[str, np.ndarray]  # measured 'pA', 'pB', 'x' (x from theta if needed); NaN filled
    valid: dict[str, np.ndarray]  # bool masks: sample was measured (not NaN)
    smooth: dict[str, np.ndarray]  # smoothed pA, pB, x, v, a, dpA, dpB
    x_s: np.ndarray  # spool position from the model's own spool dynamics (exact: depends on u only)
    dx_s: np.ndarray
    metadata: dict[str, str]
    scored: dict[str, np.ndarray]  # bool masks: measured, and away from the model's known gaps (gap_mask)
    u_filled: int = 0  # samples of the input u that were missing (NaN), interpolated
    saturated: dict = field(default_factory=dict)  # column -> [samples, Pa] at a transmitter's ceiling (not scored)
    position: str = "x"  # the position column the recording gave: "x" (a linear transducer) or "theta" (the encoder)
    columns: frozenset = frozenset()  # every signal column of the recording

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def duration(self) -> float:
        return self.n * self.dt


def _label(rec: Recording) -> str:
    return str(rec.source) if rec.source is not None else "recording"


def _fill_nan(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(y)
    if ok.all():
        return y.astype(float), ok
    idx = np.arange(len(y))
    return np.interp(idx, idx[ok], y[ok]), ok


_NAMES = {"x": "the position", "u": "the input 'u'"}


def missing_note(data: Prepared) -> str | None:
    """The warning for samples a recording lacks (NaN, or a pressure at its transmitter's ceiling):
    filled in for the simulation, never scored."""
    counts = {k: int((~v).sum()) - data.saturated.get(k, [0])[0] for k, v in data.valid.items()}
    counts = {k: n for k, n in counts.items() if n}
    if data.u_filled:
        counts = {"u": data.u_filled, **counts}
    said = []
    if counts:
        which = ", ".join(f"{n} in {_NAMES.get(k, repr(k))}" for k, n in counts.items())
        said.append(f"missing (NaN) samples, {which}")
    said += [f"{n} sample(s) of '{k}' flat at {top / 1e6:.4g} MPa, a transmitter at the top of its range"
             for k, (n, top) in data.saturated.items()]
    return f"{data.name}: {'; '.join(said)}: interpolated for the simulation and not scored" if said else None


def prepare(rec: Recording, plant: Plant, *, role: str = "recording", min_duration: float = MIN_DURATION_S,
            settings: Settings = Settings()) -> Prepared:
    """Check a recording and build a :class:`Prepared` from it (raises UserError)."""
    label = _label(rec)
    for col in ("u", "pA", "pB"):
        if col not in rec.signals:
            raise UserError(f"{label}: missing column '{col}' ({role} needs t, u, pA, pB and x or theta)")
    if "x" not in rec.signals and "theta" not in rec.signals:
        raise UserError(f"{label}: missing column 'x' or 'theta' ({role} needs the piston position or the joint angle)")
    if rec.n < 10:
        raise UserError(f"{label}: only {rec.n} samples; too short to separate hypotheses")
    dt = rec.dt
    duration = rec.n * dt
    if duration < min_duration:
        raise UserError(
            f"{label}: {duration:.2f} s long; too short to separate hypotheses "
            f"(need at least {min_duration:g} s: two segments to fit, one to hold out)"
        )
    u, u_measured = _fill_nan(rec.signals["u"])
    if np.ptp(u) < MIN_INPUT_RANGE_V:
        raise UserError(
            f"{label}: 'u': the input does not excite the system (range {np.ptp(u):.3g} V around {np.mean(u):.3g} V); "
            f"a diagnosis needs the valve driven in both directions or at least varied by {MIN_INPUT_RANGE_V} V"
        )
    b = plant.boom
    y, valid, saturated = {}, {}, {}
    for col in ("pA", "pB"):
        top = at_ceiling(rec.signals[col], dt)  # a cut-off reading is not the pressure: missing, not scored
        if top.any():
            saturated[col] = [int(top.sum()), float(rec.signals[col][top][0])]
        y[col], valid[col] = _fill_nan(np.where(top, np.nan, rec.signals[col]))
    if "x" in rec.signals:
        y["x"], valid["x"] = _fill_nan(rec.signals["x"])
    else:
        th, valid["x"] = _fill_nan(rec.signals["theta"])
        y["x"] = piston_position(th, b.L_1, b.L_2, b.L_3)
    x_max = plant.cylinder.x_max
    if np.nanmin(y["x"]) < -0.05 * x_max or np.nanmax(y["x"]) > 1.05 * x_max:
        raise UserError(
            f"{label}: piston position spans {np.min(y['x']):.3f}..{np.max(y['x']):.3f} m, outside the stroke "
            f"0..{x_max:.3f} m of plant '{plant.name}': wrong plant or wrong geometry"
        )
    p_hi = 2.5 * plant.supply.p_S
    for col in ("pA", "pB"):
        if np.max(y[col]) > p_hi:
            raise UserError(
                f"{label}: '{col}' reaches {np.max(y[col]) / 1e6:.1f} MPa, far above the supply pressure "
                f"{plant.supply.p_S / 1e6:.1f} MPa of plant '{plant.name}': wrong plant?"
            )
    n_sub = max(1, int(math.ceil(dt / settings.max_step_s - 1e-9)))
    smooth = _smooth(y, dt, rec.signals.get("v"))
    x_s, dx_s = spool_trajectory(plant, u, dt / n_sub, n_sub, settings.scheme)
    gap = gap_mask(y, dt, plant, settings)
    return Prepared(
        name=label, t=np.asarray(rec.t, float), dt=dt, n_sub=n_sub, u=u, y=y, valid=valid, smooth=smooth,
        x_s=x_s, dx_s=dx_s, metadata=dict(rec.metadata), scored={k: valid[k] & ~gap for k in valid},
        position="x" if "x" in rec.signals else "theta", columns=frozenset(rec.signals), saturated=saturated,
        u_filled=int((~u_measured).sum()),
    )


def sensor_limits(data: Prepared) -> list[str]:
    """What this recording's sensor set and sampling rate keep the diagnosis from telling apart."""
    out = []
    if "pS" not in data.columns:
        out.append("no supply pressure (pS) is recorded: supply droop cannot be told from a valve flow limit or "
                   "a transmitter lag by the chamber pressures alone, nor a pump's limit from a meter-in flow cap, nor "
                   "the relief's override from a line loss; a pS transmitter at the valve settles the first two")
    if data.position == "theta":
        out.append("the position is the joint encoder's theta, turned into x through the plant's geometry: an error "
                   "of the geometry (lengths, level angle) shows in the position as well as in the load, and is "
                   "calibrated, not named; a linear transducer on the piston (x) separates the two")
    if data.dt > 1.0001e-3:
        out.append(f"sampled at {1 / data.dt:.0f} Hz: a transmitter lag or delay shorter than one sample "
                   f"({1e3 * data.dt:.0f} ms) is not resolved, and a lag is told from a delay only well above "
                   f"{3e3 * data.dt:.0f} ms; log at 1 kHz or faster")
    return out


def gap_mask(y: dict[str, np.ndarray], dt: float, plant: Plant, settings: Settings) -> np.ndarray:
    """Samples where the model's form is known to differ from a real machine's, and for
    ``settings.gap_hold_s`` after: the piston within ``settings.stop_band_m`` of an end stop (sam's
    stops are inelastic, a real one gives and rebounds) and a chamber pressure below
    ``settings.low_pressure_Pa`` (sam clamps a cavitating chamber at its floor, a real one opens a
    void that closes later; transmitters clip at 0). No effect of the library is judged there."""
    b = plant.boom
    end = float(stroke_end(plant.cylinder.x_max, b.theta_max, b.L_1, b.L_2, b.L_3))
    near = (y["x"] < settings.stop_band_m) | (y["x"] > end - settings.stop_band_m)
    near |= (y["pA"] < settings.low_pressure_Pa) | (y["pB"] < settings.low_pressure_Pa)
    hold = int(round(settings.gap_hold_s / dt))
    if hold > 0 and near.any():
        near = np.convolve(near.astype(float), np.ones(hold + 1), mode="full")[:len(near)] > 0
    return near


def _window(dt: float, seconds: float, poly: int) -> int:
    w = max(poly + 2, int(round(seconds / dt)) | 1)
    return w if w % 2 else w + 1


def _smooth(y: dict[str, np.ndarray], dt: float, v_meas: np.ndarray | None) -> dict[str, np.ndarray]:
    """Savitzky-Golay smoothed signals and derivatives (for initial states and the generic route)."""
    wp = _window(dt, 0.021, 2)
    wx = _window(dt, 0.041, 3)
    out = {
        "pA": savgol_filter(y["pA"], wp, 2),
        "pB": savgol_filter(y["pB"], wp, 2),
        "dpA": savgol_filter(y["pA"], wp, 2, deriv=1, delta=dt),
        "dpB": savgol_filter(y["pB"], wp, 2, deriv=1, delta=dt),
        "x": savgol_filter(y["x"], wx, 3),
        "v": savgol_filter(y["x"], wx, 3, deriv=1, delta=dt),
        "a": savgol_filter(y["x"], _window(dt, 0.061, 3), 3, deriv=2, delta=dt),
    }
    if v_meas is not None and np.isfinite(v_meas).all():
        out["v"] = np.asarray(v_meas, float)
    return out


def spool_trajectory(plant: Plant, u: np.ndarray, dt_sim: float, n_sub: int,
                     scheme: str = "heun") -> tuple[np.ndarray, np.ndarray]:
    """Spool position and rate at each sample, from the model's spool dynamics (Eq. (15)).

    The spool depends on the input alone, so one run of the model gives it exactly.
    """
    p = plant.vector()[None, :]
    uu = np.repeat(u, n_sub)
    rec_at = np.arange(0, len(uu), n_sub)
    res = simulate_batch(p, uu, dt_sim, record_at=rec_at, channels=("x_s", "dx_s"), scheme=scheme)
    return res["x_s"][0], res["dx_s"][0]


def check_segment(seg_s: float, data: Prepared, validation: Prepared | None = None) -> None:
    """Refuse a segment length the diagnosis cannot use, instead of silently using another one:
    it must be at least MIN_SEGMENT_S, the recording must hold three segments (the segment
    simulator shortens them otherwise) and a validation recording one."""
    if not (math.isfinite(seg_s) and seg_s >= MIN_SEGMENT_S):
        raise UserError(f"--segment {seg_s:g} s: a segment must be at least {MIN_SEGMENT_S:g} s (each starts "
                        f"with a 30 ms transient that is not scored)")
    limits = [(data.duration / 3, f"{data.name} ({data.duration:.1f} s) must hold three segments")]
    if validation is not None:
        limits.append((validation.duration, f"{validation.name} ({validation.duration:.1f} s) must hold one"))
    longest, why = min(limits)
    if seg_s > longest:
        raise UserError(f"--segment {seg_s:g} s: {why}; use --segment {math.floor(100 * longest) / 100:g} or less")


def sampling_note(data: Prepared, validation: Prepared) -> str | None:
    """A warning when the validation recording is sampled at another rate than the recording."""
    if abs(validation.dt - data.dt) <= 0.01 * data.dt:
        return None
    return (f"the validation recording {validation.name} is sampled every {1e3 * validation.dt:g} ms, the "
            f"recording every {1e3 * data.dt:g} ms: the model is simulated on each file's own sample grid, so "
            f"the held-out fit is measured at another rate than the fit (resample one of them to compare like "
            f"with like)")


def check_same_plant(main: Prepared, other: Prepared, plant: Plant, other_label: str) -> None:
    """Refuse a validation recording that comes from a different plant."""
    a, b = main.metadata.get("plant"), other.metadata.get("plant")
    if a and b and a.strip() != b.strip():
        raise UserError(
            f"{other_label}: metadata 'plant' is '{b}' but the recording is from '{a}': "
            f"a validation file must come from the same machine"
        )
    pa = max(np.percentile(main.y["pA"], 99), np.percentile(main.y["pB"], 99))
    pb = max(np.percentile(other.y["pA"], 99), np.percentile(other.y["pB"], 99))
    if pb > 2.5 * pa + 1e6 or pa > 2.5 * pb + 1e6:
        raise UserError(
            f"{other_label}: pressures reach {pb / 1e6:.1f} MPa against {pa / 1e6:.1f} MPa in the recording: "
            f"incompatible ranges, not the same plant or supply"
        )


__all__ = ["Prepared", "prepare", "check_same_plant", "check_segment", "gap_mask", "sampling_note", "sensor_limits",
           "spool_trajectory", "MIN_DURATION_S", "MIN_SEGMENT_S", "P", "S"]
