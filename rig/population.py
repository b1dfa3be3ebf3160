"""A population of labelled rig recordings (``samfdi rig population``): healthy and faulty runs
drawn from a seed, each a recording with its truth in ``true_*`` columns, for scoring a fault
detector (``samfdi fdi evaluate``) on data its model did not make.

Each run is drawn on its own (:func:`draw_run`, seeded by (seed, run index)) from a
:class:`Form`: closed-loop position control (P or PI, steps, ramps with holds, work cycles or
sines as setpoints) or an open-loop input (cycles, sines, PRBS); a load of 0-800 kg, in some runs
changing; a machine off its plant file (valve flows and pressure drops, B_eff, viscous and
Coulomb friction, geometry tolerances, transmitter offsets, and in the held-out form a
transmitter lag and hoses); a fault stepping in at a random onset. :data:`DEVELOPMENT` and
:data:`HELD_OUT` are two forms apart: tune on the first, measure on the second;
:data:`OTHER_SENSORS` is the held-out form through another lab's transmitters and encoder.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sam.errors import UserError
from sam.params import GROUP_OF, P, Plant
from sam.plant import default_plant_path, load_plant
from sam.recording import Recording, write_recording
from sam.scenario import scenario_from_table

from .settings import Effects, RigSettings, Sensors, Tolerances
from .simulate import record

#: The fault cases a population holds by default: the detector's targets (leaks of 0.25 L/min at
#: 10 MPa, offsets of +-1 % of spool travel) and the next sizes up, for the rate-vs-size figure.
TARGET_CASES = (("K_int", 0.25), ("K_extA", 0.25), ("K_extB", 0.25), ("offset", 1.0), ("offset", -1.0))
LARGER_CASES = (("K_int", 0.5), ("K_extA", 0.5), ("K_extB", 0.5), ("offset", 2.0), ("offset", -2.0))
FORMATS = ("mat", "csv")


@dataclass(frozen=True)
class Form:
    """How a population's runs are drawn. Ranges are (low, high), drawn uniformly."""

    name: str = "development"
    closed_loop_share: float = 0.7  #: runs under the lab's position loop; the rest open loop
    setpoints: tuple = ("steps", "ramps", "cycle")  #: closed-loop reference kinds (sam.control)
    open_inputs: tuple = ("cycle", "sine", "prbs")  #: open-loop input kinds (sam.profiles)
    kp_V_per_m: tuple = (200.0, 400.0)
    pi_share: float = 0.3  #: closed-loop runs with an integral term
    ki_V_per_m_s: tuple = (20.0, 60.0)
    dither_share: float = 0.0
    amplitude_V: tuple = (2.0, 4.0)  #: open-loop input amplitude
    #: the start positions' and setpoints' range [m]; inside the SAM's reachable 0.437 m (its joint
    #: limit theta_max), and never beyond 90 % of a plant's stroke
    stroke_m: tuple = (0.03, 0.40)
    load_kg: tuple = (0.0, 800.0)
    load_change_share: float = 0.3  #: runs whose load steps to another (healthy runs; fault runs before onset)
    healthy_s: tuple = (20.0, 60.0)  #: length of a healthy run
    onset_s: tuple = (4.0, 8.0)  #: a fault's onset
    after_onset_s: tuple = (3.0, 6.0)  #: recorded after it
    #: the machine off its plant file: relative half-widths of uniform draws around the plant's values
    machine: dict = field(default_factory=lambda: {
        "Q_N_PA": 0.03, "Q_N_AT": 0.03, "Q_N_PB": 0.03, "Q_N_BT": 0.03,
        "dp_N_PA": 0.03, "dp_N_AT": 0.03, "dp_N_PB": 0.03, "dp_N_BT": 0.03,
        "B_eff": 0.15, "b": 0.30, "F_C": 0.20})
    length_sd_m: float = 0.001  #: geometry tolerance draws of the rig (rig.settings.Tolerances)
    angle_sd_rad: float = 0.01
    sensor_offset_Pa: float = 15e3  #: each transmitter's zero offset, uniform in +-this
    transmitter_lag_s: tuple = (0.0, 0.0)  #: s; a lag below ~0.3 ms is stiff for the rig's RK4 at 0.1 ms
    hose_volume_m3: tuple = (0.0, 0.0)  #: per chamber, hoses of modulus hose_modulus_Pa
    hose_modulus_Pa: float = 1e10
    #: the lab's sensors, drawn from a generator of their own so that forms which leave them at the
    #: SAM's (15 kPa transmitters, 16-bit ADC, 0.007 deg encoder) keep their runs draw for draw
    pressure_noise_Pa: tuple = (15e3, 15e3)  #: each transmitter's white noise
    adc_bits: tuple = (16,)  #: the logger's ADC resolutions, one drawn
    encoder_deg: tuple = (0.007,)  #: encoders' pulses, one drawn (deg per count)
    delay_s: tuple = (0.0, 0.0)  #: transport delay of the pressure signals

    def __post_init__(self):
        for name in ("closed_loop_share", "pi_share", "dither_share", "load_change_share"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"Form.{name} = {getattr(self, name)!r}: must be a share in [0, 1]")


DEVELOPMENT = Form()
#: Other forms than the development set's, never tuned on: sine setpoints and dither, stiffer and
#: softer loops, more PI, chirps, ramped load changes, a wider machine box, transmitter lag, hoses.
HELD_OUT = Form(
    name="held-out", closed_loop_share=0.6, setpoints=("sine", "steps", "cycle"), open_inputs=("chirp", "cycle", "prbs"),
    kp_V_per_m=(150.0, 500.0), pi_share=0.5, ki_V_per_m_s=(10.0, 80.0), dither_share=0.3, amplitude_V=(1.5, 5.0),
    stroke_m=(0.05, 0.40), load_change_share=0.4,
    machine={"Q_N_PA": 0.04, "Q_N_AT": 0.04, "Q_N_PB": 0.04, "Q_N_BT": 0.04, "dp_N_PA": 0.04, "dp_N_AT": 0.04,
             "dp_N_PB": 0.04, "dp_N_BT": 0.04, "B_eff": 0.20, "b": 0.40, "F_C": 0.30},
    length_sd_m=0.0015, angle_sd_rad=0.015, sensor_offset_Pa=20e3, transmitter_lag_s=(0.5e-3, 2e-3),
    hose_volume_m3=(0.0, 5e-5))
#: The held-out form seen through other sensors than the SAM's, as a lab's rig would be: 5-60 kPa
#: transmitters (0.02-0.25 % of 25 MPa) through a 12- or 16-bit ADC, encoders of 0.007-0.036 deg
#: per count, a transport delay of up to 2 ms. Never tuned on.
OTHER_SENSORS = dataclasses.replace(
    HELD_OUT, name="other-sensors", pressure_noise_Pa=(5e3, 60e3), adc_bits=(12, 16),
    encoder_deg=(0.007, 0.009, 0.018, 0.036), delay_s=(0.0, 2e-3))
FORMS = {f.name: f for f in (DEVELOPMENT, HELD_OUT, OTHER_SENSORS)}


def cases(n_healthy: int, n_per_case: int, fault_cases=TARGET_CASES) -> list:
    """The runs of a population, in order: (fault or None, size) per run; sizes in L/min at
    10 MPa for leaks, % of spool travel for the offset."""
    return [(None, 0.0)] * n_healthy + [c for c in fault_cases for _ in range(n_per_case)]


def run_name(i: int, fault, size: float) -> str:
    """The file stem of run i: its index and case, e.g. ``0042_K_int_0.25``, ``0007_healthy``."""
    return f"{i:04d}_healthy" if fault is None else f"{i:04d}_{fault}_{size:+g}".replace("+", "p").replace("-", "m")


def draw_run(plant_path: Path, form: Form, seed: int, i: int, fault=None, size: float = 0.0,
             duration_s: float | None = None, onset_s: float | None = None) -> tuple[dict, RigSettings]:
    """The scenario table and rig settings of run i of a population with ``seed``: every draw
    from its own generator (seed, i). ``duration_s`` / ``onset_s``: given instead of drawn."""
    rng = np.random.default_rng((seed, i))
    plant = load_plant(plant_path)
    if fault is None:
        duration = float(rng.uniform(*form.healthy_s)) if duration_s is None else duration_s
        onset = None
    else:
        onset = float(np.round(rng.uniform(*form.onset_s), 3)) if onset_s is None else onset_s
        duration = onset + float(rng.uniform(*form.after_onset_s)) if duration_s is None else duration_s
    duration = float(np.round(duration, 3))
    table = {"description": f"{form.name} population run {i}", "plant": str(plant_path), "duration_s": duration,
             "dt_s": 1e-3, "seed": int(rng.integers(1 << 31))}
    form = dataclasses.replace(form, stroke_m=(form.stroke_m[0], min(form.stroke_m[1], 0.9 * plant.cylinder.x_max)))
    closed = rng.uniform() < form.closed_loop_share
    x0 = float(rng.uniform(*form.stroke_m))
    if closed:
        table["control"] = _control(form, rng, duration, x0)
    else:
        table["input"] = _open_input(form, rng, duration)
    table["initial"] = {"x_m": x0}
    table["load"] = _load(form, rng, duration, onset)
    table["plant_overrides"] = _machine(form, rng, plant)
    if fault is not None:
        unit = "%" if fault == "offset" else "L/min"
        table["faults"] = {fault: {"kind": "step", "value": float(size), "unit": unit, "t0_s": onset}}
    lo, hi = form.transmitter_lag_s
    hose = rng.uniform(*form.hose_volume_m3, 2)
    sensor_rng = np.random.default_rng((seed, i, 1))
    settings = RigSettings(
        sensors=Sensors(offset_A_Pa=float(rng.uniform(-1, 1) * form.sensor_offset_Pa),
                        offset_B_Pa=float(rng.uniform(-1, 1) * form.sensor_offset_Pa),
                        lag_s=float(rng.uniform(lo, hi)),
                        pressure_noise_Pa=float(sensor_rng.uniform(*form.pressure_noise_Pa)),
                        adc_bits=int(sensor_rng.choice(form.adc_bits)),
                        encoder_deg=float(sensor_rng.choice(form.encoder_deg)),
                        delay_s=float(sensor_rng.uniform(*form.delay_s))),
        effects=Effects(hose_volume_A_m3=float(hose[0]), hose_volume_B_m3=float(hose[1]),
                        hose_modulus_Pa=form.hose_modulus_Pa),
        tolerances=Tolerances(length_sd_m=form.length_sd_m, angle_sd_rad=form.angle_sd_rad))
    return table, settings


def simulate_run(plant_path: Path, form: Form, seed: int, i: int, fault=None, size: float = 0.0,
                 duration_s: float | None = None, onset_s: float | None = None) -> Recording:
    """Run i of a population on the rig (:func:`draw_run`): a recording with its truth."""
    table, settings = draw_run(plant_path, form, seed, i, fault, size, duration_s, onset_s)
    sc = scenario_from_table(table, Path(f"{run_name(i, fault, size)}.toml"))
    rec = record(sc, settings)
    meta = {**rec.metadata, "generator": "samfdi rig population", "population_form": form.name,
            "population_seed": str(seed), "population_run": str(i), "case": "healthy" if fault is None else
            f"{fault} {size:g} {'%' if fault == 'offset' else 'L/min'}"}
    return dataclasses.replace(rec, metadata=meta)


def write_population(out: Path, plant_path: Path | None, form: Form, seed: int, runs: list, fmt: str = "mat",
                     progress: bool = True) -> list[Path]:
    """Write the recordings of ``runs`` (:func:`cases`) into ``out``, one file per run named by
    :func:`run_name`. A file already there is kept (each is written whole or not at all), so a
    killed run resumes where it stopped."""
    if fmt not in FORMATS:
        raise UserError(f"--format: one of {', '.join(FORMATS)}, got {fmt!r}")
    plant_path = Path(plant_path) if plant_path is not None else default_plant_path()
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, (fault, size) in enumerate(tqdm(runs, desc=f"rig population ({form.name})", unit="run",
                                           disable=not progress)):
        path = out / f"{run_name(i, fault, size)}.{fmt}"
        if not path.exists():
            write_recording(path, simulate_run(plant_path.resolve(), form, seed, i, fault, size))
        paths.append(path)
    return paths


def _control(form: Form, rng: np.random.Generator, duration: float, x0: float) -> dict:
    lo, hi = form.stroke_m
    kind = str(rng.choice(form.setpoints))
    if kind in ("steps", "ramps"):
        t, points, x = 0.0, [[0.0, x0]], x0
        while t < duration:
            t += float(rng.uniform(2.0, 6.0))
            x = float(rng.uniform(lo, hi))
            if kind == "ramps":  # a ramp of 1-4 s, then the hold
                points.append([round(t, 3), points[-1][1]])
                t += float(rng.uniform(1.0, 4.0))
            points.append([round(t, 3), x])
        setpoint = {"kind": kind, "points": points}
    elif kind == "cycle":
        low = float(rng.uniform(lo, lo + 0.1))
        period = float(rng.uniform(8.0, 30.0))
        setpoint = {"kind": "cycle", "low_m": low, "high_m": float(rng.uniform(low + 0.1, hi)), "period_s": period,
                    "ramp_s": float(rng.uniform(1.0, period / 4)), "t0_s": float(rng.uniform(0.5, 2.0))}
    else:  # sine
        amp = float(rng.uniform(0.04, 0.12))
        setpoint = {"kind": "sine", "mean_m": float(rng.uniform(lo + amp, hi - amp)), "amplitude_m": amp,
                    "frequency_Hz": float(rng.uniform(0.05, 0.3))}
    control = {"kp_V_per_m": float(rng.uniform(*form.kp_V_per_m)), "setpoint": setpoint}
    if rng.uniform() < form.pi_share:
        control["ki_V_per_m_s"] = float(rng.uniform(*form.ki_V_per_m_s))
    if rng.uniform() < form.dither_share:
        control["dither_V"], control["dither_Hz"] = float(rng.uniform(0.02, 0.08)), float(rng.uniform(80.0, 200.0))
    return control


def _open_input(form: Form, rng: np.random.Generator, duration: float) -> dict:
    kind = str(rng.choice(form.open_inputs))
    amp = float(rng.uniform(*form.amplitude_V))
    if kind == "cycle":
        return {"kind": "cycle", "amplitude_V": amp, "period_s": float(rng.uniform(4.0, 20.0)),
                "ramp_s": float(rng.uniform(0.1, 0.5)), "dwell_fraction": float(rng.uniform(0.0, 0.5))}
    if kind == "sine":
        return {"kind": "sine", "amplitude_V": amp, "frequency_Hz": float(rng.uniform(0.1, 0.5))}
    if kind == "chirp":
        return {"kind": "chirp", "amplitude_V": amp, "f0_Hz": float(rng.uniform(0.05, 0.2)),
                "f1_Hz": float(rng.uniform(0.3, 1.0))}
    return {"kind": "prbs", "amplitude_V": amp, "hold_s": float(rng.uniform(0.2, 1.0)),
            "seed": int(rng.integers(1 << 31))}


def _load(form: Form, rng: np.random.Generator, duration: float, onset: float | None) -> dict:
    m0 = float(rng.uniform(*form.load_kg))
    last = duration - 2.0 if onset is None else onset - 2.0  # a fault run's load settles before its onset
    if rng.uniform() < form.load_change_share and last > 2.0:
        return {"kind": "step", "before_kg": m0, "after_kg": float(rng.uniform(*form.load_kg)),
                "t0_s": float(rng.uniform(1.0, last))}
    return {"m_L_kg": m0}


def _machine(form: Form, rng: np.random.Generator, plant: Plant) -> dict:
    """plant_overrides: each parameter of ``form.machine`` drawn around the plant's value."""
    nominal = plant.vector()
    out: dict = {}
    for name, rel in form.machine.items():
        value = float(nominal[P[name]] * (1.0 + rel * rng.uniform(-1, 1)))
        out.setdefault(GROUP_OF[name], {})[name] = value
    return out


def tune_recordings(plant_path: Path | None, form: str, fault, size: float, n: int, seed: int,
                    inputs: str = "standard") -> list[Recording]:
    """n runs of ``form`` (a FORMS name) for ``fdi tune --source rig`` (fdi.tune.recorded_chunk_job):
    the fault (None: healthy) of ``size`` (leaks in L/min at 10 MPa, the offset a fraction), each
    run drawn from (seed, i). ``inputs`` (the tune's input family of sam runs) is not used: every
    run draws its loop or input, and a healthy run its 20-60 s, from the form."""
    plant_path = Path(plant_path) if plant_path is not None else default_plant_path()
    size = 100.0 * size if fault == "offset" else size
    return [simulate_run(plant_path.resolve(), FORMS[form], seed, i, fault, size) for i in range(n)]
