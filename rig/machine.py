"""The rig's machine: the plant file and the ``[rig.*]`` tables, as one flat vector of constants.

The compiled right-hand side (:mod:`rig.model`) reads a float64 vector laid out by
:class:`rig.layout.C`.
It is built here, once per run, from a :class:`sam.params.Plant` (read through sam's plant
loader: parsing is not dynamics) and :class:`rig.settings.RigSettings`. The rig's geometry is
the plant file's plus the tolerances; its boom conventions are contract C1's ``theta_level`` and
``cog_angle``, today's reconstruction when the plant has no such fields.
"""

from __future__ import annotations

import math

import numpy as np

from sam.errors import UserError, where
from sam.params import Effects as SamEffects, Plant

from .layout import N_CONSTANTS, C
from .mechanics import piston_position
from .settings import RigSettings

def boom_conventions(plant: Plant) -> tuple[float, float]:
    """(theta_level, cog_angle) [rad] of the plant file's boom (docs/model.md, "Boom conventions")."""
    return float(plant.boom.theta_level), float(plant.boom.cog_angle)


def joint_geometry(plant: Plant, settings: RigSettings, rng: np.random.Generator) -> dict[str, float]:
    """The rig's true geometry: the plant file's, the tolerances' deviations and their seeded draws."""
    b, tol = plant.boom, settings.tolerances
    theta_level, cog_angle = boom_conventions(plant)
    lengths = {"L_1": b.L_1, "L_2": b.L_2, "L_3": b.L_3, "L": b.L, "r_B": b.r_B}
    angles = {"theta_level": theta_level, "cog_angle": cog_angle}
    out = {}
    for name, value in lengths.items():
        out[name] = value + getattr(tol, f"{name}_m") + tol.length_sd_m * rng.standard_normal()
    for name, value in angles.items():
        out[name] = value + getattr(tol, f"{name}_rad") + tol.angle_sd_rad * rng.standard_normal()
    return out


def build(plant: Plant, settings: RigSettings, rng: np.random.Generator, source=None) -> np.ndarray:
    """The machine vector (N_CONSTANTS,) of ``plant`` as the rig ``settings`` make it.

    ``rng`` draws the geometry tolerances (seeded by the scenario). A plant file with sam's own
    optional effects (``[effects]``) is refused: they are terms of sam's model, and the rig has
    its own, in ``[rig.effects]``."""
    if plant.effects != SamEffects():
        raise UserError(f"{where(source, 'plant')}: the plant's [effects] are sam's model terms; the rig "
                        f"takes its own in [rig.effects] (docs/rig.md)")
    v, s, cyl, fr, e, st = plant.valve, plant.supply, plant.cylinder, plant.friction, settings.effects, settings.stops
    geo = joint_geometry(plant, settings, rng)
    c = np.zeros(N_CONSTANTS)
    for name in ("L_1", "L_2", "L_3", "L", "r_B", "theta_level", "cog_angle"):
        c[C[name]] = geo[name]
    if not abs(geo["L_1"] - geo["L_2"]) < geo["L_3"] < geo["L_1"] + geo["L_2"]:
        raise UserError(f"{where(source, 'rig.tolerances')}: the toleranced lengths do not close the cylinder triangle")
    b = plant.boom
    c[C.m_B], c[C.m_L], c[C.m_R] = b.m_B, b.m_L, b.m_R
    c[C.J_fixed] = b.m_B * b.L_B**2 / 12.0 + b.m_R * geo["L"] ** 2 + e.extra_inertia_kg_m2
    c[C.gyration_sq] = geo["L"] ** 2 + e.load_gyration_m**2
    c[C.x_max] = cyl.x_max
    c[C.x_end] = min(cyl.x_max, piston_position(b.theta_max, geo["L_1"], geo["L_2"], geo["L_3"]))
    c[C.A_A] = math.pi * cyl.D_piston**2 / 4.0
    c[C.A_B] = c[C.A_A] - math.pi * cyl.D_rod**2 / 4.0
    c[C.V_0A], c[C.V_0B] = cyl.V_0A, cyl.V_0B
    c[C.hose_A], c[C.hose_B], c[C.hose_modulus] = e.hose_volume_A_m3, e.hose_volume_B_m3, e.hose_modulus_Pa
    c[C.B] = plant.fluid.B_eff
    c[C.air_content], c[C.air_dissolved], c[C.air_tau] = e.air_content, e.air_dissolved_Pa, e.air_time_constant_s
    for edge in ("PA", "AT", "PB", "BT"):
        # Eq. (12): K_v = Q_N / sqrt(dp_N)
        c[C[f"K_{edge}"]] = getattr(v, f"Q_N_{edge}") / math.sqrt(getattr(v, f"dp_N_{edge}"))
        c[C[f"lap_{edge}"]] = getattr(e, f"lap_{edge}")
        c[C[f"KL_{edge}"]] = getattr(v, f"K_leak_{edge}")
    c[C.port] = e.port_flow_m3_s / math.sqrt(v.dp_N_PA)  # inf: no restriction
    c[C.full_area] = e.full_area_opening
    c[C.leak_band], c[C.K_u], c[C.omega_n], c[C.zeta] = v.leak_band, v.K_u, v.omega_n, v.zeta
    c[C.leak_taper] = e.leak_band_taper
    c[C.notch_knee], c[C.notch_exponent] = e.notch_knee, e.notch_exponent
    c[C.stiction], c[C.dp_laminar], c[C.offset] = e.spool_stiction, e.orifice_transition_Pa, v.offset
    c[C.spool_sliding] = e.spool_sliding_share
    c[C.bypass] = e.bypass_m3_s_Pa
    c[C.p_S], c[C.p_T] = s.p_S, s.p_T
    c[C.pump], c[C.V_line] = e.pump_flow_m3_s, e.line_volume_m3
    # the relief passes the whole pump flow at the plant's p_S, and opens relief_override below it
    c[C.relief_crack] = s.p_S - e.relief_override_Pa
    c[C.relief_gain] = e.pump_flow_m3_s / e.relief_override_Pa if math.isfinite(e.pump_flow_m3_s) else 0.0
    c[C.F_C], c[C.F_S], c[C.v_s], c[C.sigma_0], c[C.b] = fr.F_C, fr.F_S, fr.v_s, fr.sigma_0, fr.b
    c[C.seal_piston], c[C.seal_rod] = e.seal_piston_m2, e.seal_rod_m2
    c[C.k_stop], c[C.stop_damping] = st.stiffness_N_per_m, st.damping_s_per_m
    c[C.lag] = settings.sensors.lag_s
    c[C.reduced_mass_motion] = 0.0 if e.arm_rate_torque else 1.0
    return c
