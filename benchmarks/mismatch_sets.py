"""The mismatch diagnosis' proof sets, recorded on the rig simulator (``rig/``), never by ``sam``.

Two sets, both made here from fixed seeds (the rig records 20 s in about 0.2 s, so nothing is
checked in):

* ``dev``: the development set, which the diagnosis may be tuned on. Each library effect in the
  rig's own form at three magnitudes, each under a closed and an open loop, over three loads; at
  least 20 clean recordings (inputs, loads 100-700 kg, B_eff 0.6-1.6 GPa, valve flows within
  +-10 %, geometry within its tolerance); the effects no library holds; two effects at once.
* ``heldout``: other magnitudes, forms, seeds, and the ways a foreign rig differs: logged at
  500 Hz or 2 kHz, theta instead of x, other controller gains, other sensor noise, a boom
  geometry convention other than the plant file's. Never tuned on.

The diagnosis is always given the default plant file (``scenarios/plants/sam.toml``); what the
rig's machine is, is in each case. ::

    python benchmarks/mismatch_sets.py --set dev --out DIR     # writes DIR/<case>.csv (with true_*)
    python benchmarks/mismatch_sets.py --set heldout --list    # the cases, one line each
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import rig
import sam
from sam.scenario import scenario_from_table

ROOT = Path(__file__).resolve().parents[1]
#: Where the scenario tables say they come from (plant paths resolve against it).
SOURCE = ROOT / "scenarios" / "rig" / "mismatch_case.toml"
LPM = 1.0 / 60000.0
#: The stroke the inputs use [m]: clear of both end stops (the extension stop is the joint limit, 0.4375 m).
X_LOW, X_HIGH = 0.03, 0.40
#: What the library calls an effect that no library hypothesis describes.
UNKNOWN = "unknown effect"


@dataclass(frozen=True)
class Case:
    """One recording: what the rig's machine is and how it is run and logged.

    ``expect``: the library effects a diagnosis should name (first the one named first for a single
    effect; the set for two), () for a clean recording, (UNKNOWN,) for an effect no library holds.
    """

    name: str
    expect: tuple[str, ...]
    effects: dict = field(default_factory=dict)  #: rig.Effects keys
    plant: dict = field(default_factory=dict)  #: the rig's machine, by sam's flat names (not m_L)
    sensors: dict = field(default_factory=dict)  #: rig.Sensors keys
    tolerances: dict = field(default_factory=dict)  #: rig.Tolerances keys
    loop: str = "closed"  #: "closed" (P/PI position control on the encoder) or "open" (an operator's input)
    load_kg: float = 494.0
    seed: int = 1
    rate_Hz: float = 1000.0  #: logger rate (and the controller's, up to 1 kHz)
    kp: float = 300.0  #: V/m
    ki: float = 0.0  #: V/(m s)
    position: str = "x"  #: the position column the diagnosis gets: "x" or "theta"
    duration_s: float = 20.0
    group: str = ""  #: the row of the summary table it counts in
    magnitude: str = ""  #: in words

    @property
    def kind(self) -> str:
        if not self.expect:
            return "clean"
        if self.expect == (UNKNOWN,):
            return "unknown"
        return "pair" if len(self.expect) > 1 else "single"


# ------------------------------------------------------------------------------------------ inputs


def ramp_points(rng: np.random.Generator, duration: float) -> list[list[float]]:
    """A position reference: holds at random positions joined by ramps of random speed (fast moves,
    slow moves, long holds), within [X_LOW, X_HIGH]."""
    t, x = 0.0, float(rng.uniform(0.08, 0.3))
    points = [[0.0, x]]
    while t < duration:
        hold = float(rng.choice([0.3, 0.8, 1.5, 2.5]) * rng.uniform(0.7, 1.3))
        t += hold
        points.append([t, x])
        target = float(rng.uniform(X_LOW, X_HIGH))
        speed = float(rng.choice([0.03, 0.08, 0.2, 0.5]))  # m/s: slow ramps to steps the valve saturates on
        t += max(abs(target - x) / speed, 0.02)
        x = target
        points.append([t, x])
    return points


def operator_input(rng: np.random.Generator, plant: sam.Plant, load_kg: float, duration: float,
                   dt: float) -> np.ndarray:
    """An open-loop valve input as an operator gives it: levels of 1-7 V held 0.1-0.8 s, towards a
    target the operator has in mind, with rests at null, planned on sam's model (Eq. (22) at dt) so
    that the boom stays clear of the stops. The rig then runs it open loop and drifts its own way."""
    p = plant.replace(m_L=load_kg).vector()
    n = int(round(duration / dt))
    u = np.zeros(n)
    state = sam.initial_state(p[None, :], 0.2)
    k, target = 0, float(rng.uniform(X_LOW + 0.05, X_HIGH - 0.05))
    while k < n:
        x = state[0, sam.S.x]
        if abs(x - target) < 0.03 or rng.random() < 0.1:
            target = float(rng.uniform(X_LOW + 0.05, X_HIGH - 0.05))
        rest = rng.random() < 0.2
        level = 0.0 if rest else math.copysign(float(rng.uniform(1.0, 7.0)), target - x)
        hold = int(rng.uniform(0.15, 1.2) / dt)
        seg = np.full(min(hold, n - k), level)
        if not rest:
            seg += float(rng.uniform(0.0, 0.6)) * np.sin(2 * np.pi * rng.uniform(2, 8) * np.arange(len(seg)) * dt)
        # the operator's hand (or the amplifier's ramp generator) moves the command in 20-150 ms
        ramp = min(len(seg), max(1, int(rng.uniform(0.02, 0.15) / dt)))
        previous = u[k - 1] if k else 0.0
        seg[:ramp] = previous + (seg[:ramp] - previous) * np.arange(1, ramp + 1) / ramp
        # the operator lets go before the stops
        res = sam.simulate_batch(p[None, :], seg, dt, x0=state, record_at=np.arange(len(seg)), channels=("x",))
        over = np.flatnonzero((res["x"][0] < X_LOW) | (res["x"][0] > X_HIGH + 0.02))
        if over.size:
            seg = seg[:max(over[0], 1)]
        res = sam.simulate_batch(p[None, :], seg, dt, x0=state)
        state = np.array([[res[c][0, -1] for c in sam.S.__members__]])
        u[k:k + len(seg)] = seg
        k += len(seg)
    return np.clip(u, -10.0, 10.0)


# ------------------------------------------------------------------------------------------ record


def scenario(case: Case) -> tuple[sam.Scenario, rig.RigSettings]:
    """The rig scenario and settings of ``case``; its machine's plant overrides under their groups."""
    rng = np.random.default_rng(case.seed)
    dt = 1.0 / case.rate_Hz  # the logger's and the input's grid; the controller runs at 1 kHz or slower
    overrides: dict[str, dict] = {}
    for key, value in case.plant.items():
        overrides.setdefault(sam.params.GROUP_OF[key], {})[key] = value
    table = {"duration_s": case.duration_s, "dt_s": dt, "output_dt_s": 1.0 / case.rate_Hz, "seed": case.seed,
             "load": {"m_L_kg": case.load_kg}, "initial": {"x_m": 0.2}, "plant_overrides": overrides}
    if case.loop == "closed":
        table["control"] = {"rate_Hz": min(case.rate_Hz, 1000.0), "kp_V_per_m": case.kp, "ki_V_per_m_s": case.ki,
                            "dither_V": float(rng.choice([0.0, 0.3, 0.6])), "dither_Hz": float(rng.uniform(3, 12)),
                            "setpoint": {"kind": "ramps", "points": ramp_points(rng, case.duration_s)}}
        table["initial"] = {"x_m": table["control"]["setpoint"]["points"][0][1]}
    else:
        table["input"] = {"kind": "step", "amplitude_V": 0.0}
    sc = scenario_from_table(table, SOURCE)
    if case.loop == "open":
        sc = dataclasses.replace(sc, u=operator_input(rng, sc.plant, case.load_kg, case.duration_s, dt))
    settings = rig.RigSettings(sensors=rig.Sensors(**case.sensors), effects=rig.Effects(**case.effects),
                               tolerances=rig.Tolerances(**case.tolerances))
    return sc, settings


def record(case: Case) -> sam.Recording:
    """The rig's recording of ``case`` as the diagnosis gets it (the truth kept in ``true_*``), with
    only the position column ``case.position`` and the case's description in its metadata."""
    sc, settings = scenario(case)
    rec = rig.record(sc, settings)
    drop = "theta" if case.position == "x" else "x"
    signals = {k: v for k, v in rec.signals.items() if k != drop}
    meta = {**rec.metadata, "case": case.name, "concealed": case.magnitude or "nothing",
            "plant": "sam"}  # the diagnosis' plant file
    return dataclasses.replace(rec, signals=signals, metadata=meta, source=Path(f"{case.name}.csv"))


# ------------------------------------------------------------------------------------------ the sets


def _clean(seed: int, loop: str, rng: np.random.Generator, geometry: bool = True, **kw) -> Case:
    """A clean machine drawn from the commissioning box: load 100-700 kg, B_eff 0.6-1.6 GPa, notch
    flows within +-10 %, offset within +-0.5 %, geometry within its tolerance."""
    flows = {f"Q_N_{e}": 4.0e-4 * float(rng.uniform(0.9, 1.1)) for e in ("PA", "AT", "PB", "BT")}
    plant = {"B_eff": float(rng.uniform(0.6e9, 1.6e9)), "offset": float(rng.uniform(-0.005, 0.005)), **flows}
    tol = {"length_sd_m": 0.002, "angle_sd_rad": 0.01} if geometry else {}
    load = float(rng.uniform(100.0, 700.0))
    return Case(f"clean_{loop}_{seed}", (), plant=plant, tolerances=tol, loop=loop, load_kg=round(load),
                seed=seed, group="clean", magnitude=f"{load:.0f} kg, B_eff {plant['B_eff'] / 1e9:.2f} GPa", **kw)


#: (library effect, rig effect keys at three magnitudes, words) of the development set
_DEV_EFFECTS = (
    ("entrained_air", [{"air_content": a} for a in (0.005, 0.01, 0.02)], "{air_content:.1%} free air"),
    ("hose_compliance", [{"hose_volume_A_m3": v, "hose_volume_B_m3": v, "hose_modulus_Pa": e}
                         for v, e in ((2e-4, 3e8), (3e-4, 2e8), (4e-4, 1.2e8))],
     "hoses {hose_volume_A_m3:.1e} m^3 at E {hose_modulus_Pa:.1e} Pa"),
    ("spool_lap", [{"lap_PA": a, "lap_AT": a, "lap_PB": a, "lap_BT": a} for a in (0.02, 0.04, 0.07)],
     "{lap_PA:.0%} overlap"),
    ("flow_saturation", [{"full_area_opening": a} for a in (0.7, 0.5, 0.35)], "notch area full at {full_area_opening:.0%}"),
    ("supply_droop", [{"pump_flow_m3_s": q * LPM} for q in (22.0, 18.0, 15.0)], "pump {pump_flow_m3_s:.2e} m^3/s"),
    ("bypass_leakage", [{"bypass_m3_s_Pa": k} for k in (1e-12, 2.5e-12, 5e-12)], "bypass {bypass_m3_s_Pa:.1e}"),
    ("pressure_friction", [{"seal_piston_m2": k, "seal_rod_m2": k / 2} for k in (1e-4, 2e-4, 4e-4)],
     "seals {seal_piston_m2:.1e} m^2"),
    ("load_inertia", [{"extra_inertia_kg_m2": j} for j in (600.0, 1200.0, 2500.0)], "extra J {extra_inertia_kg_m2:g}"),
    ("sensor_lag", [{"lag_s": t} for t in (0.005, 0.01, 0.02)], "lag {lag_s}"),
    ("time_delay", [{"delay_s": t} for t in (0.004, 0.008, 0.015)], "delay {delay_s}"),
)
#: friction level: the rig's plant differs from the plant file's (F_C, F_S, b) [N, N, N s/m]
_DEV_FRICTION = ((2000.0, 6000.0, 5000.0), (400.0, 2000.0, 1000.0), (3000.0, 8000.0, 8000.0))
_SENSOR_KEYS = {f.name for f in dataclasses.fields(rig.Sensors)}


def _single(effect: str, spec: dict, words: str, loop: str, load: float, seed: int, **kw) -> Case:
    sensors = {k: v for k, v in spec.items() if k in _SENSOR_KEYS}
    effects = {k: v for k, v in spec.items() if k not in _SENSOR_KEYS}
    return Case(f"{effect}_{loop}_{seed}", (effect,), effects=effects, sensors=sensors, loop=loop, load_kg=load,
                seed=seed, group=effect, magnitude=words.format(**spec), **kw)


def dev_set() -> list[Case]:
    """The development set (seeds 1000-1999)."""
    cases = []
    loads = (200.0, 450.0, 650.0)
    seed = 1000
    for effect, specs, words in _DEV_EFFECTS:
        for j, spec in enumerate(specs):
            for loop in ("closed", "open"):
                seed += 1
                cases.append(_single(effect, spec, words, loop, loads[(j + (loop == "open")) % 3], seed))
    for j, (F_C, F_S, b) in enumerate(_DEV_FRICTION):
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"friction_level_{loop}_{seed}", ("friction_level",),
                              plant={"F_C": F_C, "F_S": F_S, "b": b}, loop=loop,
                              load_kg=loads[(j + (loop == "open")) % 3], seed=seed, group="friction_level",
                              magnitude=f"F_C {F_C:g}, F_S {F_S:g}, b {b:g}"))
    rng = np.random.default_rng(1)
    for i in range(22):
        seed += 1
        cases.append(_clean(seed, "closed" if i % 2 == 0 else "open", rng))
    for name, effects in (("progressive_notch", {"notch_knee": 0.3, "notch_exponent": 2.0}),
                          ("valve_hysteresis", {"hysteresis_V": 0.6}),
                          ("sticking_spool", {"spool_stiction": 0.03})):
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"{name}_{loop}_{seed}", (UNKNOWN,), effects=effects, loop=loop, load_kg=450.0,
                              seed=seed, group=name, magnitude=str(effects)))
    pairs = (
        (("entrained_air", "bypass_leakage"), {"air_content": 0.01, "bypass_m3_s_Pa": 3e-12}, {}),
        (("entrained_air", "pressure_friction"), {"air_content": 0.01, "seal_piston_m2": 2e-4, "seal_rod_m2": 1e-4}, {}),
        (("sensor_lag", "time_delay"), {}, {"lag_s": 0.012, "delay_s": 0.004}),
    )
    for expect, effects, sensors in pairs:
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"{'+'.join(expect)}_{loop}_{seed}", expect, effects=effects, sensors=sensors,
                              loop=loop, load_kg=450.0, seed=seed, group="two effects", magnitude="pair"))
    return cases


def heldout_set() -> list[Case]:
    """The held-out set (seeds 5000-5999): other magnitudes, other forms of each effect, other
    machines and loggers. Written before the first held-out run and never tuned on."""
    rng = np.random.default_rng(5)
    cases: list[Case] = []
    seed = 5000
    # how a foreign rig is run and logged, cycled over the cases
    rigs = ({}, {"rate_Hz": 500.0}, {"position": "theta"}, {"kp": 150.0, "ki": 40.0},
            {"sensors": {"pressure_noise_Pa": 40e3, "adc_bits": 12}}, {"rate_Hz": 2000.0})

    def foreign(i: int) -> dict:
        return dict(rigs[i % len(rigs)])

    for i in range(14):
        seed += 1
        kw = foreign(i)
        cases.append(_clean(seed, "closed" if i % 3 else "open", rng, **kw))
    # the other boom convention (docs/model.md's independent reconstruction) and an off-drawing boom
    for i, (plant, tol, words) in enumerate((({"theta_level": 0.415}, {}, "level at theta 0.415 rad"),
                                             ({}, {"theta_level_rad": 0.2, "r_B_m": 0.05, "L_m": 0.05},
                                              "level +0.2 rad, r_B +5 cm, L +5 cm"))):
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"clean_geometry_{loop}_{seed}", (), plant=plant, tolerances=tol, loop=loop,
                              load_kg=float(rng.uniform(150, 650)), seed=seed, group="clean", magnitude=words))
    singles = (
        ("entrained_air", {"air_content": 0.008, "air_time_constant_s": 0.05}, "0.8 % air, fast release"),
        ("entrained_air", {"air_content": 0.015, "air_dissolved_Pa": 8e6}, "1.5 % air dissolving by 8 MPa"),
        ("hose_compliance", {"hose_volume_A_m3": 3.5e-4, "hose_volume_B_m3": 1.5e-4, "hose_modulus_Pa": 1.5e8},
         "hoses A 3.5e-4, B 1.5e-4 m^3, E 1.5e8 Pa"),
        ("hose_compliance", {"hose_volume_A_m3": 2.5e-4, "hose_volume_B_m3": 2.5e-4, "hose_modulus_Pa": 2.5e8},
         "hoses 2.5e-4 m^3, E 2.5e8 Pa"),
        ("spool_lap", {"lap_PA": 0.05, "lap_AT": 0.03, "lap_PB": 0.05, "lap_BT": 0.03}, "5 %/3 % overlap (asymmetric)"),
        ("spool_lap", {"lap_PA": 0.03, "lap_AT": 0.03, "lap_PB": 0.03, "lap_BT": 0.03}, "3 % overlap"),
        ("flow_saturation", {"port_flow_m3_s": 3.0e-4}, "port restriction 18 L/min"),
        ("flow_saturation", {"full_area_opening": 0.45}, "notch area full at 45 %"),
        ("supply_droop", {"pump_flow_m3_s": 16.0 * LPM, "line_volume_m3": 5e-4}, "pump 16 L/min, 0.5 L line"),
        ("supply_droop", {"pump_flow_m3_s": 20.0 * LPM}, "pump 20 L/min"),
        ("bypass_leakage", {"bypass_m3_s_Pa": 2e-12}, "bypass 2e-12"),
        ("bypass_leakage", {"bypass_m3_s_Pa": 4e-12}, "bypass 4e-12"),
        ("pressure_friction", {"seal_piston_m2": 3e-4}, "piston seal 3e-4 m^2 only"),
        ("pressure_friction", {"seal_piston_m2": 1.5e-4, "seal_rod_m2": 1.5e-4}, "seals 1.5e-4 m^2"),
        ("load_inertia", {"load_gyration_m": 0.8}, "load gyration radius 0.8 m"),
        ("load_inertia", {"extra_inertia_kg_m2": 1800.0}, "extra J 1800"),
        ("sensor_lag", {"lag_s": 0.008}, "lag 8 ms"),
        ("sensor_lag", {"lag_s": 0.015}, "lag 15 ms"),
        ("time_delay", {"delay_s": 0.006}, "delay 6 ms"),
        ("time_delay", {"delay_s": 0.012}, "delay 12 ms"),
    )
    for i, (effect, spec, words) in enumerate(singles):
        for loop in ("closed", "open"):
            seed += 1
            kw = foreign(i + (loop == "open"))
            load = float(rng.choice([150.0, 350.0, 550.0, 700.0]))
            cases.append(_single(effect, {**spec, **kw.pop("sensors", {})}, words, loop, load, seed, **kw))
    for j, (F_C, F_S, b) in enumerate(((1500.0, 4000.0, 4000.0), (2500.0, 5000.0, 800.0))):
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"friction_level_{loop}_{seed}", ("friction_level",),
                              plant={"F_C": F_C, "F_S": F_S, "b": b}, loop=loop, load_kg=400.0, seed=seed,
                              group="friction_level", magnitude=f"F_C {F_C:g}, F_S {F_S:g}, b {b:g}"))
    for name, effects in (("progressive_notch", {"notch_knee": 0.2, "notch_exponent": 3.0}),
                          ("valve_hysteresis", {"hysteresis_V": 0.4}),
                          ("sticking_spool", {"spool_stiction": 0.05, "spool_sliding_share": 0.3})):
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"{name}_{loop}_{seed}", (UNKNOWN,), effects=effects, loop=loop, load_kg=350.0,
                              seed=seed, group=name, magnitude=str(effects)))
    pairs = (
        (("hose_compliance", "bypass_leakage"),
         {"hose_volume_A_m3": 3e-4, "hose_volume_B_m3": 3e-4, "hose_modulus_Pa": 2e8, "bypass_m3_s_Pa": 3e-12}, {}),
        (("pressure_friction", "sensor_lag"), {"seal_piston_m2": 2.5e-4, "seal_rod_m2": 1e-4}, {"lag_s": 0.01}),
        (("entrained_air", "time_delay"), {"air_content": 0.012}, {"delay_s": 0.008}),
    )
    for expect, effects, sensors in pairs:
        for loop in ("closed", "open"):
            seed += 1
            cases.append(Case(f"{'+'.join(expect)}_{loop}_{seed}", expect, effects=effects, sensors=sensors,
                              loop=loop, load_kg=float(rng.uniform(200, 600)), seed=seed, group="two effects",
                              magnitude="pair"))
    return cases


def reduced(cases: list[Case], per_group: int = 1) -> list[Case]:
    """The first ``per_group`` closed-loop cases of every group (the slow tests' share of a set)."""
    out, seen = [], {}
    for c in cases:
        if c.loop == "closed" and seen.get(c.group, 0) < per_group:
            seen[c.group] = seen.get(c.group, 0) + 1
            out.append(c)
    return out


SETS = {"dev": dev_set, "heldout": heldout_set}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=sorted(SETS), default="dev")
    ap.add_argument("--out", type=Path, default=None, help="write DIR/<case>.csv")
    ap.add_argument("--case", action="append", help="only these cases (repeatable)")
    ap.add_argument("--list", action="store_true", help="list the cases")
    args = ap.parse_args(argv)
    for case in SETS[args.set]():
        if args.case and case.name not in args.case:
            continue
        if args.list or args.out is None:
            print(f"{case.name:40s} {case.kind:8s} {'+'.join(case.expect) or '-':32s} {case.magnitude}")
            continue
        print(sam.write_recording(args.out / f"{case.name}.csv", record(case), overwrite=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
