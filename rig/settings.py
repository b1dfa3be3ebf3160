"""What the rig knows that the plant file does not: the ``[rig.*]`` tables of a scenario.

The plant file describes the machine as its owner believes it to be, for ``sam`` and the rig
alike. These tables describe the rig itself: its integrator, its end stops, its sensors and
logger, the effects a real machine has and the plant file does not say (each neutral by
default), and how far its geometry is off the drawing::

    [rig.numerics]     step_s = 1e-4
    [rig.stops]        stiffness_N_per_m = 2e9, damping_s_per_m = 10
    [rig.sensors]      pressure_noise_Pa = 15e3, adc_bits = 16, ...
    [rig.effects]      air_content = 0.005, lap_PA = 0.01, pump_flow_m3_s = 5e-4, ...
    [rig.tolerances]   L_3_m = 0.002, length_sd_m = 0.001, ...

Every value is SI; every key and value is checked here, once, and a bad one is named in one
line. The physics never checks.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from sam.errors import UserError, did_you_mean, where


def knob(default, lo: float = -math.inf, hi: float = math.inf, *, open_lo: bool = False):
    """A dataclass field with its allowed range [lo, hi] (or (lo, hi] with ``open_lo``)."""
    return field(default=default, metadata={"lo": lo, "hi": hi, "open_lo": open_lo})


@dataclass(frozen=True)
class Numerics:
    """The rig's integrator: fixed-step classical Runge-Kutta (RK4)."""

    step_s: float = knob(1e-4, 0.0, 1e-3, open_lo=True)  #: s, internal step; must divide dt_s


@dataclass(frozen=True)
class Stops:
    """End stops as Hunt-Crossley contacts, ``k d (1 + 1.5 alpha d')`` for a penetration d, at x = 0
    and at the extension end (the stroke or the joint limit theta_max, whichever comes first)."""

    stiffness_N_per_m: float = knob(2e9, 0.0, open_lo=True)  #: N/m, k at the piston
    damping_s_per_m: float = knob(10.0, 0.0)  #: s/m, alpha: the fraction of an impact's speed lost per m/s


@dataclass(frozen=True)
class Sensors:
    """The lab's transmitters, encoder and logger (Appendix 1)."""

    pressure_noise_Pa: float = knob(15e3, 0.0)  #: Pa, white noise of each pressure transmitter
    adc_bits: float = knob(16, 0, 32)  #: bits of the logger's ADC over the transmitter's range; 0: none
    pressure_full_scale_Pa: float = knob(25e6, 0.0, open_lo=True)  #: Pa, range 0..full scale (clipped)
    encoder_deg: float = knob(0.007, 0.0)  #: deg per count of the joint encoder; 0: exact angle
    lag_s: float = knob(0.0, 0.0, 1.0)  #: s, first-order lag of the pressure transmitters
    delay_s: float = knob(0.0, 0.0, 1.0)  #: s, transport delay of the pressure signals
    offset_A_Pa: float = knob(0.0)  #: Pa, zero offset of transmitter A
    offset_B_Pa: float = knob(0.0)  #: Pa, zero offset of transmitter B
    measure_pS: bool = False  #: also log the supply pressure (at the valve)
    measure_v: bool = False  #: also log the piston velocity
    measure_xs: bool = False  #: also log the spool position


@dataclass(frozen=True)
class Effects:
    """Physics of a real machine that the plant file does not hold; each neutral by default."""

    # entrained air that dissolves with pressure (free air per unit oil volume at atmospheric pressure)
    air_content: float = knob(0.0, 0.0, 0.5)  #: 1, free air at equilibrium at atmospheric pressure
    air_dissolved_Pa: float = knob(5e6, 0.0, open_lo=True)  #: Pa, gauge pressure where all of it has dissolved
    air_time_constant_s: float = knob(0.2, 0.0, open_lo=True)  #: s, of dissolution and release
    # seal friction rising with pressure: F_C and F_S grow by these times the pressures on the seals
    seal_piston_m2: float = knob(0.0, 0.0)  #: m^2, times |p_A - p_B| (piston seal)
    seal_rod_m2: float = knob(0.0, 0.0)  #: m^2, times p_B (rod seal)
    # overlap of each metering edge, fraction of travel (< 0: underlap)
    lap_PA: float = knob(0.0, -0.2, 0.2)
    lap_AT: float = knob(0.0, -0.2, 0.2)
    lap_PB: float = knob(0.0, -0.2, 0.2)
    lap_BT: float = knob(0.0, -0.2, 0.2)
    # a progressive notch: below the knee the open area grows as knee (a / knee)^exponent
    notch_knee: float = knob(0.0, 0.0, 1.0)  #: 1, opening where the notch ends; 0: none
    notch_exponent: float = knob(2.0, 1.0, 4.0)  #: 1
    #: m^3/s, a port restriction in series with each metering edge, passing this at the edge's dp_N
    #: fully open by itself; inf: none. The valve's flow saturates at it as the spool opens.
    port_flow_m3_s: float = knob(math.inf, 0.0, open_lo=True)
    #: 1, the opening at which a notch has uncovered its whole port: its area grows no further
    full_area_opening: float = knob(1.0, 0.0, 1.0, open_lo=True)
    hysteresis_V: float = knob(0.0, 0.0, 2.0)  #: V, width of the play between command and spool
    spool_stiction: float = knob(0.0, 0.0, 0.2)  #: 1, spool-position error that breaks a resting spool free
    spool_sliding_share: float = knob(0.5, 0.0, 1.0)  #: 1, its sliding friction over its breakaway
    # pump-limited supply: a fixed pump, a relief valve and the line volume between them and the valve
    pump_flow_m3_s: float = knob(math.inf, 0.0, open_lo=True)  #: m^3/s; inf: an ideal source at p_S
    relief_override_Pa: float = knob(0.5e6, 0.0, open_lo=True)  #: Pa, from cracking to full pump flow
    line_volume_m3: float = knob(1e-3, 0.0, open_lo=True)  #: m^3, pump to valve
    bypass_m3_s_Pa: float = knob(0.0, 0.0)  #: m^3/(s Pa), laminar leak across the piston
    # hoses between the valve and the cylinder: their oil, and the swelling of their walls
    hose_volume_A_m3: float = knob(0.0, 0.0)
    hose_volume_B_m3: float = knob(0.0, 0.0)
    hose_modulus_Pa: float = knob(math.inf, 0.0, open_lo=True)  #: Pa, V_hose (1 + p / this)
    # the load is a body, not a point: its inertia about its centre, and more inertia on the boom
    load_gyration_m: float = knob(0.0, 0.0)  #: m, J_load = m_L (this)^2 about its own centre
    extra_inertia_kg_m2: float = knob(0.0, 0.0)
    #: 1, the null leakage of Eqs. (13)-(14) fades out over this outer fraction of its band
    leak_band_taper: float = knob(0.1, 0.0, 1.0, open_lo=True)
    # orifices turn laminar below this pressure drop (at the Reynolds number where a jet forms)
    orifice_transition_Pa: float = knob(5e3, 0.0, 1e6, open_lo=True)
    #: false: the boom moves as sam's Eq. (19) has it, m_reduced x'' = F, which drops the torque
    #: J r'(theta) omega^2 / r of a lever arm that changes as the boom turns (Eq. (7)'s R-dot term;
    #: Eq. (16), which the rig integrates, keeps it). For checking the rig against sam.
    arm_rate_torque: bool = True


@dataclass(frozen=True)
class Tolerances:
    """How far the rig's geometry is from the plant file: fixed deviations plus seeded draws."""

    L_1_m: float = knob(0.0, -0.05, 0.05)
    L_2_m: float = knob(0.0, -0.05, 0.05)
    L_3_m: float = knob(0.0, -0.05, 0.05)
    L_m: float = knob(0.0, -0.5, 0.5)
    r_B_m: float = knob(0.0, -0.2, 0.2)
    theta_level_rad: float = knob(0.0, -0.3, 0.3)
    cog_angle_rad: float = knob(0.0, -0.5, 0.5)
    length_sd_m: float = knob(0.0, 0.0, 0.01)  #: m, standard deviation of a draw on each length
    angle_sd_rad: float = knob(0.0, 0.0, 0.05)  #: rad, ... on each angle


@dataclass(frozen=True)
class RigSettings:
    """All of ``[rig.*]``."""

    numerics: Numerics = Numerics()
    stops: Stops = Stops()
    sensors: Sensors = Sensors()
    effects: Effects = Effects()
    tolerances: Tolerances = Tolerances()


_CLASSES = {"numerics": Numerics, "stops": Stops, "sensors": Sensors, "effects": Effects,
            "tolerances": Tolerances}


def parse_rig(table: dict[str, Any] | None, source) -> RigSettings:
    """``[rig]`` of a scenario (its sub-tables), validated; the defaults for what is not given."""
    table = {} if table is None else table
    if not isinstance(table, dict):
        raise UserError(f"{where(source, 'rig')}: expected tables [rig.numerics], [rig.sensors], ...")
    groups = {}
    for name, spec in table.items():
        if name not in _CLASSES:
            raise UserError(f"{where(source, f'rig.{name}')}: unknown table{did_you_mean(name, _CLASSES)}; "
                            f"allowed: {sorted(_CLASSES)}")
        if not isinstance(spec, dict):
            raise UserError(f"{where(source, f'rig.{name}')}: expected a table [rig.{name}]")
        groups[name] = _group(_CLASSES[name], spec, source, f"rig.{name}")
    return RigSettings(**groups)


def _group(cls, spec: dict, source, prefix: str):
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, value in spec.items():
        if key not in fields:
            raise UserError(f"{where(source, f'{prefix}.{key}')}: unknown key{did_you_mean(key, fields)}; "
                            f"allowed: {sorted(fields)}")
        values[key] = _value(fields[key], value, source, f"{prefix}.{key}")
    return cls(**values)


def _value(f: dataclasses.Field, value, source, name: str):
    if isinstance(f.default, bool):
        if not isinstance(value, bool):
            raise UserError(f"{where(source, name)}: expected true or false, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
        raise UserError(f"{where(source, name)}: expected a number in SI units, got {value!r}")
    lo, hi, open_lo = f.metadata["lo"], f.metadata["hi"], f.metadata["open_lo"]
    if math.isinf(value) and not math.isinf(f.default):
        raise UserError(f"{where(source, name)}: must be finite, got {value}")
    if value < lo or value > hi or (open_lo and value == lo):
        left = "(" if open_lo else "["
        raise UserError(f"{where(source, name)}: must be in {left}{lo:g}, {hi:g}], got {value!r}")
    return float(value)
