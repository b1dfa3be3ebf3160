"""What would settle it: the input that tells two look-alike hypotheses apart.

When the recording leaves two effects close (entrained air against hose compliance, a lag
against a delay, a friction level against seal friction), each fitted with its own calibration,
the two models predict nearly the same recording, and no statistic on it can choose. Another
recording can: this module simulates both fitted models under a few excitations a test engineer
can run (a slow pressure ramp, a fast reversal, a hold at null, a step at high load), measures
how far apart their predictions fall in units of the transmitters' noise, and returns the one
that separates them most, as a scenario the user runs (``samfdi simulate FILE`` on the model,
the same [input] on the machine).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sam import P, initial_state, simulate_batch
from sam.measurement import first_order_lag, time_delay
from sam.profiles import INPUT_KINDS, evaluate

from .fitting import FitResult
from .simulation import SegmentSimulator

#: Logging step of the designed runs [s].
DT = 1e-3


@dataclass(frozen=True)
class Excitation:
    """An open-loop test: its ``[input]`` table (sam.profiles), start position and length."""

    name: str
    shows: str  #: what it makes visible
    x0_m: float
    duration_s: float
    input: dict
    high_load: bool = False  #: run it at the top of the load's range


EXCITATIONS = (
    Excitation("slow pressure ramp", "the chamber's compliance at each pressure, as p_A builds slowly against "
               "the load from the retracted stop until it lifts", 0.0, 5.0,
               {"kind": "ramp", "start_V": 0.0, "end_V": 1.5, "t0_s": 0.5, "t1_s": 4.5}),
    Excitation("fast reversal", "the pressures' response to a sudden reversal of the valve: the shape of a "
               "transmitter's lag against a pure delay, the oil spring", 0.2, 4.0,
               {"kind": "cycle", "amplitude_V": 4.0, "period_s": 1.0, "ramp_s": 0.005}),
    Excitation("hold at null", "the pressures relaxing with the valve centred after a move: leaks, laps, "
               "the null leakage", 0.15, 4.0,
               {"kind": "step", "amplitude_V": 0.0, "initial_V": 2.5, "t0_s": 1.0}),
    Excitation("step at high load", "a breakaway and a steady extension at a high chamber pressure: "
               "friction that grows with pressure against friction that does not", 0.05, 3.0,
               {"kind": "step", "amplitude_V": 5.0, "t0_s": 0.3}, high_load=True),
)


@dataclass(frozen=True)
class Design:
    """The excitation that separates two fitted hypotheses best."""

    first: str
    second: str
    excitation: Excitation
    load_kg: float
    separation: dict[str, float]  #: excitation name -> RMS difference of the predictions [noise sd]
    on_recording: float  #: the same on the recording itself (held-out segments) [noise sd]

    @property
    def best(self) -> float:
        return self.separation[self.excitation.name]

    def as_dict(self) -> dict:
        return {"first": self.first, "second": self.second, "excitation": self.excitation.name,
                "shows": self.excitation.shows, "load_kg": self.load_kg, "separation_noise_sd": self.separation,
                "on_recording_noise_sd": self.on_recording}

    def scenario_toml(self, plant_path: Path | None, source: str) -> str:
        """The excitation as a scenario file for ``samfdi simulate`` (open loop)."""
        e = self.excitation
        lines = [f"# What would tell '{self.first}' from '{self.second}' ({source}): a {e.name}.",
                 f"# It shows {e.shows}.",
                 f"# Fitted to the recording, the two predict this run {self.best:.1f} transmitter noise sd apart",
                 f"# (RMS over p_A and p_B), against {self.on_recording:.1f} on the recording's held-out segments.",
                 "# Run it on the machine with the same [input]; then `samfdi mismatch` on that recording.",
                 f'description = "{e.name}: separates {self.first} from {self.second}"']
        if plant_path is not None:
            lines.append(f'plant = "{Path(plant_path).resolve()}"')
        lines += [f"duration_s = {e.duration_s:g}", f"dt_s = {DT:g}", "seed = 1", "", "[input]"]
        lines += [f"{k} = {_toml(v)}" for k, v in e.input.items()]
        lines += ["", "[load]", f"m_L_kg = {self.load_kg:.1f}", "", "[initial]", f"x_m = {e.x0_m:g}", ""]
        return "\n".join(lines)


def _toml(v) -> str:
    return f'"{v}"' if isinstance(v, str) else f"{v:g}"


def predictions(fits: list[FitResult], excitation: Excitation, load_kg: float, scheme: str) -> dict[str, np.ndarray]:
    """p_A, p_B [Pa] and x [m] (len(fits), n) of each fitted model under ``excitation``, through its
    transmitters (each fit's lag and delay)."""
    n = int(round(excitation.duration_s / DT))
    t = np.arange(n) * DT
    u = evaluate(INPUT_KINDS, dict(excitation.input), t, "design", "input")
    params = np.array([f.params for f in fits])
    params[:, P.m_L] = load_kg
    res = simulate_batch(params, u, DT, x0=initial_state(params, excitation.x0_m), scheme=scheme)
    out = {"pA": res["p_A"][:, :n].copy(), "pB": res["p_B"][:, :n].copy(), "x": res["x"][:, :n]}
    for i, f in enumerate(fits):
        tau, delay = f.meas
        for k in ("pA", "pB"):
            if tau > 0:
                out[k][i] = first_order_lag(out[k][i], DT, tau)
            if delay > 0:
                out[k][i] = time_delay(out[k][i], DT, delay)
    return out


def separate(first: tuple[str, FitResult], second: tuple[str, FitResult], noise_Pa: float, load_kg: float,
             high_load_kg: float, on_recording: float, scheme: str) -> Design:
    """Simulate both fitted hypotheses under every excitation; the one whose predictions differ most
    (RMS over p_A and p_B, in units of the transmitters' noise ``noise_Pa``)."""
    separation = {}
    for e in EXCITATIONS:
        y = predictions([first[1], second[1]], e, high_load_kg if e.high_load else load_kg, scheme)
        d = np.concatenate([y[k][0] - y[k][1] for k in ("pA", "pB")])
        separation[e.name] = float(np.sqrt(np.mean(d ** 2)) / max(noise_Pa, 1.0))
    best = max(EXCITATIONS, key=lambda e: separation[e.name])
    return Design(first[0], second[0], best, high_load_kg if best.high_load else load_kg, separation, on_recording)


#: Pairs of effects that a recording can leave alike (each fitted with its own calibration).
LOOK_ALIKE = (frozenset({"entrained_air", "hose_compliance"}), frozenset({"sensor_lag", "time_delay"}),
              frozenset({"friction_level", "pressure_friction"}))


def partner(name: str) -> str | None:
    """The effect that ``name`` is most easily taken for, if it has one in :data:`LOOK_ALIKE`."""
    for pair in LOOK_ALIKE:
        if name in pair:
            return next(iter(pair - {name}))
    return None


def transmitter_noise(pA: np.ndarray, smooth_pA: np.ndarray) -> float:
    """The pressure transmitters' noise [Pa]: the spread of p_A about its smoothed trajectory
    (median absolute deviation, robust to the transients the smoothing rounds off)."""
    d = pA - smooth_pA
    return float(1.4826 * np.median(np.abs(d - np.median(d))))


def held_out_separation(sim: SegmentSimulator, first: FitResult, second: FitResult, noise_Pa: float) -> float:
    """RMS difference [noise sd] of two fitted models' p_A, p_B over the held-out segments of ``sim``."""
    outs = [sim.simulate(f.params[None, :], f.meas[None, :] if np.any(f.meas) else None) for f in (first, second)]
    held = sim.segment_mask("held")
    d = np.concatenate([(outs[0][k][0] - outs[1][k][0])[held].ravel() for k in ("pA", "pB")])
    return float(np.sqrt(np.mean(d ** 2)) / max(noise_Pa, 1.0))


def settle(split, data, cands: list, chosen: list, plant, scheme: str, close: float) -> tuple[dict, Design | None]:
    """How sure the first named effect is, and what would settle it.

    Returns the runner-up (the best-ranked other effect, fitted alone), its margin (its held-out BIC
    change minus the first's: positive = behind; and the held-out fit points between them), and a
    :class:`Design` against the first effect's look-alike partner (:data:`LOOK_ALIKE`) or, without
    one, against a runner-up that was accepted too and is less than ``close`` behind."""
    if not chosen:
        return {}, None
    by = {c.name: c for c in cands}
    first = by[chosen[0].hypothesis[0].name]
    named = {h.name for h in chosen[0].hypothesis}
    others = [c for c in cands if c.name not in named]
    out: dict = {}
    if others:
        ru = others[0]
        out = {"first": first.name, "runner_up": ru.name, "runner_up_title": ru.title,
               "runner_up_accepted": ru.accepted, "margin_bic_held": ru.delta_bic_held - first.delta_bic_held,
               "margin_fit_points": first.fit_after["mean"] - ru.fit_after["mean"]}
    rival = by.get(partner(first.name))
    if rival is None and others and others[0].accepted and out["margin_bic_held"] < close:
        rival = others[0]
    if rival is None or rival.name in named:
        return out, None
    y, sm = data.y["pA"], data.smooth["pA"]
    ok = np.isfinite(y)
    noise = transmitter_noise(y[ok], sm[ok])
    m_L = float(first.result.params[P.m_L])
    high = float(plant.uncertain["m_L"][1]) if "m_L" in plant.uncertain else 1.5 * m_L
    on_rec = held_out_separation(split.held_sim, first.result, rival.result, noise)
    return out, separate((first.name, first.result), (rival.name, rival.result), noise, m_L, high, on_rec, scheme)


__all__ = ["Design", "EXCITATIONS", "Excitation", "LOOK_ALIKE", "partner", "predictions", "separate", "settle",
           "transmitter_noise"]
