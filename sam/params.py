"""Plant parameters: typed dataclasses, and their packing into one flat vector.

The dataclasses are what a person reads and writes (through a plant TOML file).
The compiled model works on a flat ``float64`` vector per run, laid out by the
:data:`P` enumeration, so that a batch of parameter sets is simply an array of
shape ``(n_runs, len(P))``. One field of a dataclass is one entry of that vector,
under the same name: there is no second list of names to keep in step.

All values are SI: m, m^2, m^3, s, kg, N, Pa, rad. Paper symbols are those of
Nurmi & Mattila (2011), Appendix 2.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


@dataclass(frozen=True)
class Valve:
    """4/3 servo valve, Eqs. (10)-(15)."""

    Q_N_PA: float  #: m^3/s, nominal flow Q_N of notch P->A at full opening and dp_N_PA
    Q_N_AT: float  #: m^3/s, nominal flow of notch A->T
    Q_N_PB: float  #: m^3/s, nominal flow of notch P->B
    Q_N_BT: float  #: m^3/s, nominal flow of notch B->T
    dp_N_PA: float  #: Pa, nominal pressure difference Delta p_N of notch P->A
    dp_N_AT: float  #: Pa
    dp_N_PB: float  #: Pa
    dp_N_BT: float  #: Pa
    K_leak_PA: float  #: m^3/(s Pa), laminar null-leakage coefficient K_vPA,leak, Eq. (13)
    K_leak_AT: float  #: m^3/(s Pa)
    K_leak_PB: float  #: m^3/(s Pa)
    K_leak_BT: float  #: m^3/(s Pa)
    leak_band: float  #: 1, null leakage flows while |x_s| < leak_band (0.01 in the paper)
    K_u: float  #: 1/V, gain K from control signal to spool position
    omega_n: float  #: rad/s, spool natural frequency
    zeta: float  #: 1, spool damping ratio d_r
    offset: float = 0.0  #: 1, spool offset, fraction of full travel (a fault input)


@dataclass(frozen=True)
class Supply:
    p_S: float  #: Pa, supply pressure (gauge)
    p_T: float = 0.0  #: Pa, tank pressure (gauge)


@dataclass(frozen=True)
class Cylinder:
    D_piston: float  #: m, piston diameter; A_A = pi D_piston^2 / 4
    D_rod: float  #: m, rod diameter; A_B = A_A - pi D_rod^2 / 4
    x_max: float  #: m, stroke
    V_0A: float  #: m^3, dead volume of chamber A (piston side)
    V_0B: float  #: m^3, dead volume of chamber B (rod side)


@dataclass(frozen=True)
class Fluid:
    B_eff: float  #: Pa, effective bulk modulus B_eff (same in both chambers)


@dataclass(frozen=True)
class Friction:
    """LuGre friction, Eq. (17); sigma_1 = 2 sqrt(sigma_0 m_reduced) is derived."""

    F_C: float  #: N, Coulomb friction
    F_S: float  #: N, static friction
    v_s: float  #: m/s, Stribeck velocity
    sigma_0: float  #: N/m, bristle stiffness
    b: float  #: N s/m, viscous friction


@dataclass(frozen=True)
class Boom:
    """Geometry and masses of Eqs. (3)-(5), (16), (20)-(21); see docs/model.md."""

    L_1: float  #: m, boom joint to upper cylinder joint
    L_2: float  #: m, boom joint to lower cylinder joint
    L_3: float  #: m, cylinder joint distance at full retraction
    L: float  #: m, load distance from the boom joint
    L_B: float  #: m, boom length
    r_B: float  #: m, boom height: distance of the boom's centre of gravity from the joint
    theta_level: float  #: rad, joint angle theta at which the boom is level: phi = theta - theta_level
    cog_angle: float  #: rad, direction of the centre of gravity in the boom's frame, from the m_L arm, up positive
    m_B: float  #: kg, boom mass
    m_L: float  #: kg, left load mass (raised by extension)
    m_R: float  #: kg, right load mass
    theta_max: float  #: rad, mechanical joint limit: the extension end stop


@dataclass(frozen=True)
class Effects:
    """Optional physics, neutral by default; the mismatch diagnosis switches them on.

    Each one is a small term of the same model (see sam/hydraulics.py and
    sam/friction.py), not a second model.
    """

    air_fraction: float = 0.0  #: 1, free-air volume fraction at atmospheric pressure
    lap: float = 0.0  #: 1, spool overlap (+, a deadband) or underlap (-), fraction of travel
    Q_sat: float = math.inf  #: m^3/s, flow limit of each valve notch
    R_supply: float = 0.0  #: Pa s/m^3, supply pressure droop per flow drawn (with a pump: the relief's override)
    K_bypass: float = 0.0  #: m^3/(s Pa), laminar cylinder bypass leakage A->B
    C_hose: float = 0.0  #: m^3/Pa, extra hose compliance on each chamber
    k_fric_p: float = 0.0  #: m^2, pressure-dependent Coulomb friction: F_C + k_fric_p (p_A + p_B)
    k_fric_dp: float = 0.0  #: m^2, piston-seal friction per pressure difference across it: + k_fric_dp |p_A - p_B|
    k_fric_rod: float = 0.0  #: m^2, rod-seal friction per rod-side pressure: + k_fric_rod p_B
    x_open: float = math.inf  #: 1, spool opening (fraction of travel) beyond which a notch's area stops growing
    #: m^3/s, a fixed pump's delivery behind a relief valve that passes it all at p_S (its slope: R_supply)
    Q_pump: float = math.inf


@dataclass(frozen=True)
class Equations:
    """Which terms of the paper's equations the model keeps: model settings, not properties of a
    machine. Each default is the paper's Eq. (19), so a plant file that does not name them gets the
    model the paper used (docs/model.md, "Motion")."""

    #: 1 (true): keep Eq. (7)'s R-dot term, the torque of a lever arm that changes as the boom turns:
    #: dv/dt gains r'(theta) v^2 / r^2. 0 (false, the paper's Eq. (19)): neglect it.
    arm_rate_torque: bool = False


@dataclass(frozen=True)
class EndStops:
    """The piston's end stops (x = 0 and the extension stop): a model setting with a machine's values.
    By default (k_stop = 0) rigid and inelastic, as the paper's model has them: the step stops the
    piston dead there. With k_stop > 0 a spring-damper contact, Eq. (C1) of :mod:`sam.contact`,
    which gives and rebounds as a real stop does (docs/model.md, "End stops")."""

    k_stop: float = 0.0  #: N/m, the contact's stiffness seen at the piston; 0: rigid and inelastic
    #: 1, the contact's damping ratio at the reduced mass of Eq. (20), c = 2 zeta sqrt(k m); it sets
    #: the restitution (:func:`sam.contact.restitution`): 0 rebounds at the impact speed
    zeta_stop: float = 0.0


@dataclass(frozen=True)
class Faults:
    """Turbulent fault leakages, Eqs. (41)-(43). The spool offset is in :class:`Valve`."""

    K_int: float = 0.0  #: m^3/(s Pa^0.5), internal leakage A->B
    K_extA: float = 0.0  #: m^3/(s Pa^0.5), external leakage from A
    K_extB: float = 0.0  #: m^3/(s Pa^0.5), external leakage from B


@dataclass(frozen=True)
class Disturbances:
    """Unknown inputs: the UKF's load-force state and the mismatch diagnosis' probes."""

    F_d: float = 0.0  #: N, extra force opposing extension, added to F_ext
    Q_dA: float = 0.0  #: m^3/s, extra flow into chamber A
    Q_dB: float = 0.0  #: m^3/s, extra flow into chamber B


@dataclass(frozen=True)
class Uncertain:
    """The plant parameters its owner does not know exactly, each with the range [low, high] (SI) it
    lies in: the ``[uncertain]`` section of a plant file. What commissioning would fix (the load,
    the boom geometry, the valve's flows, B_eff): the mismatch diagnosis calibrates them within
    these ranges, and the fault detector may treat them as nuisance. Faults are not here.

    ``ranges``: ((flat plant name, low, high), ...) in the order given.
    """

    ranges: tuple[tuple[str, float, float], ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(name for name, _, _ in self.ranges)

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __getitem__(self, name: str) -> tuple[float, float]:
        """(low, high) of parameter ``name``; KeyError when it is not uncertain."""
        for key, lo, hi in self.ranges:
            if key == name:
                return lo, hi
        raise KeyError(f"{name} is not an uncertain parameter of this plant")

    def __len__(self) -> int:
        return len(self.ranges)

    def box(self, names=None) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) arrays of ``names`` (default: all, in order): the box to search or draw from."""
        names = self.names if names is None else tuple(names)
        bounds = np.array([self[name] for name in names], dtype=np.float64).reshape(len(names), 2)
        return bounds[:, 0], bounds[:, 1]


@dataclass(frozen=True)
class Plant:
    """Everything the model needs about one machine, and what of it is uncertain."""

    name: str
    valve: Valve
    supply: Supply
    cylinder: Cylinder
    fluid: Fluid
    friction: Friction
    boom: Boom
    effects: Effects = field(default_factory=Effects)
    equations: Equations = field(default_factory=Equations)
    stops: EndStops = field(default_factory=EndStops)
    uncertain: Uncertain = field(default_factory=Uncertain)

    def replace(self, **values: float) -> "Plant":
        """A copy with parameters changed by their flat name, e.g. ``replace(B_eff=1e9)``."""
        groups = {g.name: getattr(self, g.name) for g in _plant_groups()}
        for key, value in values.items():
            group = GROUP_OF[key]
            if group not in groups:
                raise KeyError(f"{key} is not a plant parameter")
            groups[group] = dataclasses.replace(groups[group], **{key: value})
        return dataclasses.replace(self, **groups)

    def vector(self, faults: Faults = Faults(), disturbances: Disturbances = Disturbances()) -> np.ndarray:
        """The flat parameter vector, shape ``(len(P),)``, in the order of :data:`P`."""
        flat = {}
        for obj in (*[getattr(self, g.name) for g in _plant_groups()], faults, disturbances):
            flat.update(dataclasses.asdict(obj))
        return np.array([flat[name] for name in PARAM_NAMES], dtype=np.float64)


def _plant_groups() -> tuple[dataclasses.Field, ...]:
    """The parameter groups of a Plant: every field but its name and its uncertainty."""
    return tuple(f for f in dataclasses.fields(Plant) if f.name not in ("name", "uncertain"))


_GROUP_TYPES = {
    "valve": Valve,
    "supply": Supply,
    "cylinder": Cylinder,
    "fluid": Fluid,
    "friction": Friction,
    "boom": Boom,
    "effects": Effects,
    "faults": Faults,
    "disturbances": Disturbances,
    "equations": Equations,  # new groups go last: the columns before them keep their index
    "stops": EndStops,
}

#: Flat parameter name -> its group ("valve", "boom", ...).
GROUP_OF: dict[str, str] = {
    f.name: group for group, cls in _GROUP_TYPES.items() for f in dataclasses.fields(cls)
}

#: The names of the flat parameter vector, in order.
PARAM_NAMES: tuple[str, ...] = tuple(GROUP_OF)

#: Index of each parameter in the flat vector: ``p[P.Q_N_PA]``. Usable inside numba code.
P = IntEnum("P", [(name, i) for i, name in enumerate(PARAM_NAMES)])
