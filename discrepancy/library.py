"""The library of candidate effects: hypotheses about physics the nominal model leaves out.

Each hypothesis names the parameters it frees. Every one of them is either a
field of :class:`sam.params.Effects` / a plant parameter (the physics lives in
``sam``'s one model, switched on through that extension point) or a
measurement-side parameter (sensor lag, time delay) applied to the simulated
signals. Nothing here writes an equation of the model.

Bounds are wide on purpose (realistic magnitudes span decades); log-scaled
parameters are searched in log10 space from a grid of starts.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sam import P, Plant


@dataclass(frozen=True)
class Free:
    """One free parameter: a flat plant name (or a measurement-side name), its box and scaling.

    ``apply`` (optional): how the value enters the plant vectors when it is not a plant parameter
    itself, ``apply(params (m, len(P)), values (m,))`` in place."""

    name: str
    lo: float
    hi: float
    log: bool = True
    unit: str = ""
    label: str = ""  # how an engineer says it
    apply: Callable | None = field(default=None, compare=False)

    def to_theta(self, value: float) -> float:
        value = min(max(value, self.lo), self.hi)
        return math.log10(value) if self.log else value / self.span

    def to_value(self, theta: float) -> float:
        return 10.0 ** theta if self.log else theta * self.span

    @property
    def span(self) -> float:
        return max(abs(self.lo), abs(self.hi))

    @property
    def theta_bounds(self) -> tuple[float, float]:
        return self.to_theta(self.lo), self.to_theta(self.hi)


@dataclass(frozen=True)
class Hypothesis:
    name: str
    title: str  # engineer's words
    params: tuple[Free, ...]
    description: str
    shows: str  # the signature: where it shows in the data
    #: starting values, grouped into families: the forms of the effect that one optimiser run cannot
    #: move between (a pump behind a relief against the plain droop); each family's best start is optimised
    families: tuple[tuple[dict[str, float], ...], ...] = field(default_factory=tuple)
    probe: dict[str, float] = field(default_factory=dict)  # a small realistic magnitude for the signature
    nominal: dict[str, float] = field(default_factory=dict)  # the plant's value, for effects that change one
    alike: str = ""  # other physics with the same signature, that the data cannot tell apart from this one

    @property
    def starts(self) -> tuple[dict[str, float], ...]:
        """Every starting value, family after family."""
        return tuple(s for family in self.families for s in family)

    def summary(self, values: dict[str, float]) -> str:
        parts = []
        for f in self.params:
            v = values[f.name]
            parts.append(f"{f.label or f.name} = {format_value(v, f.unit)}")
        return ", ".join(parts)


def format_value(v: float, unit: str) -> str:
    if unit == "%":
        return f"{100 * v:.3g} %"
    if unit == "MPa":
        return f"{v / 1e6:.3g} MPa"
    if unit == "L/min":
        return f"{v * 6e4:.3g} L/min"
    if unit == "ms":
        return f"{v * 1e3:.3g} ms"
    if unit == "L/min/MPa":
        return f"{v * 6e4 * 1e6:.3g} L/min per MPa"
    return f"{v:.4g} {unit}".strip()


#: m^2: the seal terms' range, from a seal's contact too small to matter (1e-8 m^2 at 10 MPa is 0.1 N)
#: to one that would hold the piston's own area (A_A is 5e-3 m^2 on the default plant).
K_SEAL_LO, K_SEAL_HI = 1e-8, 1e-3
#: 1: the opening limit's range, fraction of travel: a port uncovered within 2 % of travel, to beyond
#: full travel (|x_s| <= 1 at 10 V; above 1 the limit is never reached: the nominal valve).
X_OPEN_LO, X_OPEN_HI = 0.02, 1.2


def extra_inertia(params: np.ndarray, J: np.ndarray) -> None:
    """Add J [kg m^2] to the boom's inertia about its joint through the boom length L_B
    (J_B = m_B L_B^2 / 12, Eq. (16)): the one parameter that changes the inertia and nothing else."""
    params[:, P.L_B] = np.sqrt(params[:, P.L_B] ** 2 + 12.0 * J / params[:, P.m_B])


def library(plant: Plant, calibrated: frozenset[str] = frozenset()) -> tuple[Hypothesis, ...]:
    """The candidate effects for this plant (bounds scale with its nominal values). A hypothesis
    whose parameters are all ``calibrated`` is no effect but a commissioning value, and is left out
    (the load's mass when the plant file marks it uncertain)."""
    return tuple(h for h in _library(plant) if not {f.name for f in h.params} <= calibrated)


def _library(plant: Plant) -> tuple[Hypothesis, ...]:
    Q_N = max(plant.valve.Q_N_PA, plant.valve.Q_N_PB)
    f = plant.friction
    m_L = plant.boom.m_L
    J_B = plant.boom.m_B * plant.boom.L_B ** 2 / 12.0
    return (
        Hypothesis(
            "entrained_air", "entrained air (pressure-dependent bulk modulus)",
            (Free("air_fraction", 1e-5, 0.1, True, "%", "free air at atmospheric pressure"),),
            "Free air in the oil makes the fluid soft at low pressure: the effective bulk modulus falls "
            "steeply below a few MPa.",
            "pressure transients lag and ring less at low chamber pressure; worse in the low-pressure chamber",
            families=(tuple({"air_fraction": a} for a in (1e-4, 1e-3, 5e-3, 2e-2)),),
            probe={"air_fraction": 2e-3},
            alike="any compliance that falls with pressure, e.g. a hose that stiffens as it is pressurised; "
                  "the library's hose term is pressure-independent, so such a hose is named entrained air",
        ),
        Hypothesis(
            "hose_compliance", "hose or line compliance",
            (Free("C_hose", 1e-15, 1e-10, True, "m^3/Pa", "hose compliance per chamber"),),
            "Flexible hoses add a capacitance to each chamber that does not scale with the chamber volume.",
            "slower pressure build-up in every transient, most where the chamber volume is small (near the stroke ends)",
            families=(tuple({"C_hose": c} for c in (1e-13, 5e-13, 2e-12, 1e-11)),),
            probe={"C_hose": 5e-13},
        ),
        Hypothesis(
            "spool_lap", "valve spool overlap / underlap (deadband)",
            (Free("lap", -0.15, 0.15, False, "", "lap (+ overlap, - underlap), fraction of travel"),),
            "A spool overlap is a deadband around null; an underlap opens all four edges a little around null.",
            "mismatch concentrated where the spool is near null and at velocity reversals",
            families=(tuple({"lap": a} for a in (-0.04, -0.01, 0.01, 0.04)),),
            probe={"lap": 0.02},
        ),
        Hypothesis(
            "flow_saturation", "valve flow saturation (a notch fully open beyond an opening)",
            (Free("x_open", X_OPEN_LO, X_OPEN_HI, True, "%", "opening at which a notch is fully open"),),
            "A metering notch stops growing in area once the spool has uncovered its whole port: beyond that "
            "opening the valve is a fixed orifice, its flow still rising with the square root of the pressure drop "
            "(effective opening min(|x_s|, x_open) in Eqs. (10)-(12)).",
            "velocity and pressures flatten at large spool openings (high flow demand); the flow still follows "
            "the load pressure there",
            families=(tuple({"x_open": a} for a in (0.2, 0.35, 0.5, 0.7, 0.9)),),
            probe={"x_open": 0.6},
            alike="a port or line restriction in series with the valve (its flow also saturates at a fixed area); "
                  "a pilot stage that caps the flow itself (sam's Q_sat) flattens the flow against the pressure drop too",
        ),
        Hypothesis(
            "supply_droop", "supply pressure droop with flow (a pump behind a relief valve, an accumulator)",
            (Free("Q_pump", 0.1 * Q_N, 4.0 * Q_N, True, "L/min", "pump delivery"),
             Free("R_supply", 1e7, 1e12, True, "Pa s/m^3", "supply droop per flow (the relief's override)")),
            "A fixed pump behind a relief valve: the supply pressure droops linearly with the flow drawn while "
            "the relief passes the rest (its override, R_supply), then falls to whatever makes the valve pass "
            "the pump's whole delivery (Q_pump) once the relief shuts. A pump larger than the valve can draw is "
            "the plain linear droop.",
            "inflow-side chamber pressure falls at high flow demand; velocity capped at Q_pump over the "
            "inflow area, the cap higher retracting (annulus) than extending; the outflow side unaffected",
            # two families: the linear droop (a pump beyond the valve's draw, where Q_pump has no gradient),
            # and pumps the valve can outdraw (the velocity capped)
            families=(tuple({"Q_pump": 4.0 * Q_N, "R_supply": r} for r in (3e8, 2e9, 1e10, 5e10)),
                      tuple({"Q_pump": Q_N * a, "R_supply": r} for a in (0.5, 0.75, 1.1) for r in (5e8, 2e9))),
            probe={"Q_pump": 0.75 * Q_N, "R_supply": 2e9},
            alike="without pS, a flow limit on the supply edges alone (a meter-in restriction, a pilot that caps "
                  "the flow) caps the velocity alike; the relief's override and a line loss have the same droop",
        ),
        Hypothesis(
            "bypass_leakage", "laminar cylinder bypass leakage (A to B)",
            (Free("K_bypass", 1e-15, 1e-9, True, "L/min/MPa", "bypass conductance"),),
            "Flow past the piston seal, proportional to the pressure difference.",
            "pressure difference collapses when the valve is near null; velocity drift under load",
            families=(tuple({"K_bypass": k} for k in (1e-13, 1e-12, 5e-12, 3e-11)),),
            probe={"K_bypass": 2e-12},
        ),
        Hypothesis(
            "pressure_friction", "seal friction rising with the pressures the seals hold",
            (Free("k_fric_dp", K_SEAL_LO, K_SEAL_HI, True, "m^2", "piston seal, per pressure difference |p_A - p_B|"),
             Free("k_fric_rod", K_SEAL_LO, K_SEAL_HI, True, "m^2", "rod seal, per rod-side pressure p_B")),
            "A seal's lip is pressed onto its surface by the pressure it seals: the piston seal's friction grows "
            "with the pressure difference across the piston, the rod seal's with the rod-side pressure "
            "(F_C + k_piston |p_A - p_B| + k_rod p_B, and F_S alike).",
            "force balance off where the load pressure is high, worst at stick-slip and reversals",
            families=(tuple({"k_fric_dp": k, "k_fric_rod": k * r} for k in (1e-5, 5e-5, 2e-4) for r in (0.1, 1.0)),),
            probe={"k_fric_dp": 5e-5, "k_fric_rod": 2.5e-5},
        ),
        Hypothesis(
            "friction_level", "changed Coulomb / Stribeck / viscous friction",
            (Free("F_C", max(f.F_C / 20, 10.0), f.F_C * 20, True, "N", "Coulomb friction"),
             Free("F_S", max(f.F_S / 20, 10.0), f.F_S * 20, True, "N", "static friction"),
             Free("b", 1.0, max(f.b, 100.0) * 20, True, "N s/m", "viscous friction")),
            "The seal friction level differs from the nominal plant.",
            "force balance off when moving (Coulomb, viscous) or at breakaway (static); reversals",
            families=(tuple({"F_C": f.F_C * a, "F_S": f.F_S * a, "b": max(f.b, 100.0) * c}
                            for a in (0.3, 1.0, 3.0) for c in (0.3, 1.0, 3.0)),),
            probe={"F_C": f.F_C * 2, "F_S": f.F_S * 2},
            nominal={"F_C": f.F_C, "F_S": f.F_S, "b": f.b},
        ),
        Hypothesis(
            "load_mass", "load mass or inertia error",
            (Free("m_L", 1.0, max(m_L, 100.0) * 6, True, "kg", "load mass"),),
            "The load on the boom differs from the plant file: gravity load and inertia both change.",
            "steady load pressure (p_A A_A - p_B A_B) off everywhere, more so in acceleration",
            families=(tuple({"m_L": max(m_L, 100.0) * a} for a in (0.3, 0.7, 1.4, 2.5)),),
            probe={"m_L": max(m_L, 100.0) * 1.2},
            nominal={"m_L": m_L},
        ),
        Hypothesis(
            "load_inertia", "load inertia beyond the load's mass (a long or distributed load, extra mass on the boom)",
            (Free("J_extra", -0.8 * J_B, 6.0 * J_B, False, "kg m^2", "extra inertia about the joint",
                  apply=extra_inertia),),
            "The boom and its load resist acceleration more (or less) than the plant file's masses at "
            "their distances say: a load with a radius of gyration of its own, attachments.",
            "pressure transients at accelerations and the hydraulic mode's frequency off, the steady load pressure right",
            families=(tuple({"J_extra": J_B * a} for a in (-0.4, 0.5, 1.5, 4.0)),),
            probe={"J_extra": 0.5 * J_B},
        ),
        Hypothesis(
            "sensor_lag", "pressure transmitter lag (first-order)",
            (Free("tau_sensor", 1e-4, 0.2, True, "ms", "transmitter time constant"),),
            "The pressure transmitters (or their filters) respond with a first-order lag.",
            "the measured pressures trail the simulation in fast transients",
            families=(tuple({"tau_sensor": t} for t in (1e-3, 5e-3, 2e-2)),),
            probe={"tau_sensor": 5e-3},
            alike="any transmitter or filter dynamics; a higher-order filter lies between a lag and a delay",
        ),
        Hypothesis(
            "time_delay", "pressure signal delay (transport / logging)",
            (Free("delay_sensor", 1e-4, 0.15, True, "ms", "time delay"),),
            "The measured pressures are delayed with respect to the input and the position (the "
            "transmitters' electronics, the logger).",
            "the pressures are shifted in time; largest mismatch at the fastest input changes",
            families=(tuple({"delay_sensor": t} for t in (2e-3, 1e-2, 4e-2)),),
            probe={"delay_sensor": 5e-3},
            alike="a higher-order transmitter or filter lag (two cascaded lags look like a delay plus a shorter lag)",
        ),
    )


def by_name(plant: Plant) -> dict[str, Hypothesis]:
    return {h.name: h for h in _library(plant)}
