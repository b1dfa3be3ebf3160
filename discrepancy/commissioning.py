"""What commissioning would fix: the valve's notch flows, B_eff, the spool offset, and every
parameter the plant file marks as uncertain (``[uncertain]``: the load, the boom geometry, ...),
calibrated on the recording before any effect is considered.

A wrong nominal value of one of these is a commissioning matter ("recalibrated"), never missing
physics. The load and the level angle are the two the nominal model can be furthest off (the
load is rarely weighed; Fig. 3 is lost), and a least-squares calibration from the nominal values
can stall in a local minimum where the notch flows make up for a wrong load. So the calibration
starts where the recording's quasi-static force balance puts them (:func:`force_balance_start`),
as a commissioning engineer would read the load off the holding pressures.
"""

from __future__ import annotations

import math

import numpy as np

from sam import P, Plant
from sam.constants import G
from sam.geometry import cos_joint_angle, stroke_end, torque_arm, torque_arm_slope_cs

from .data import Prepared
from .fitting import FitResult, Model, Split, at, fit_by_segment
from .library import Free
from .settings import Settings

#: Calibrated always (the GSA ranks them first, Table 2), with these boxes unless the plant's
#: [uncertain] section gives a range: factor of the nominal value (notch flows, B_eff) or SI.
ALWAYS = {"Q_N_PA": (1 / 3, 3.0), "Q_N_BT": (1 / 3, 3.0), "Q_N_PB": (1 / 3, 3.0), "Q_N_AT": (1 / 3, 3.0),
          "B_eff": (0.2, 4.0), "offset": (-0.05, 0.05)}
_UNITS = {"Q_N_PA": "L/min", "Q_N_AT": "L/min", "Q_N_PB": "L/min", "Q_N_BT": "L/min", "B_eff": "MPa",
          "offset": "%", "m_L": "kg", "m_R": "kg", "m_B": "kg"}
_LABELS = {"B_eff": "bulk modulus", "offset": "spool offset (of full travel)", "m_L": "load mass",
           "theta_level": "level angle (theta where the boom is level)", "cog_angle": "boom's centre of gravity angle",
           "r_B": "boom's centre of gravity distance"}


def calibration_params(plant: Plant) -> tuple[Free, ...]:
    """The free parameters of the calibration: the notch flows, B_eff and the offset, then every
    other parameter of ``plant.uncertain``, each within its range there (else the boxes of ALWAYS).

    Positive parameters whose box spans more than a factor of 2 are searched in log10, the rest
    linearly (a load of 0-800 kg, an angle)."""
    nominal = dict(zip(P.__members__, plant.vector()))
    out = []
    names = list(ALWAYS) + [n for n in plant.uncertain.names if n not in ALWAYS]
    for name in names:
        if name in plant.uncertain:
            lo, hi = plant.uncertain[name]
        elif name == "offset":
            lo, hi = ALWAYS[name]
        else:
            lo, hi = (nominal[name] * f for f in ALWAYS[name])
        log = lo > 0 and hi / lo > 2.0
        label = _LABELS.get(name, f"nominal flow {name[4:6]}" if name.startswith("Q_N_") else name)
        out.append(Free(name, lo, hi, log, _UNITS.get(name, ""), label))
    return tuple(out)


def force_balance_start(data: Prepared, plant: Plant, calib: tuple[Free, ...], settings: Settings) -> dict[str, float]:
    """Start values of the load m_L and the level angle theta_level from the boom's force balance,
    Eq. (16) with Eq. (7)'s R-dot term, over the samples where the piston moves (|v| > MIN_SPEED):

        r (p_A A_A - p_B A_B) = J (a - r' v^2 / r^2) / r + C_1 cos(theta) + C_2 sin(theta) + r (F_C sgn v + b v)

    is linear in J, C_1, C_2, F_C and b. The gravity torque C_1 cos + C_2 sin is
    Re[e^{i theta} e^{-i theta_level} (m_L g L + m_B g r_B e^{-i cog_angle})] (contract C1), so its
    amplitude gives m_L and its phase theta_level in closed form. Only the calibrated ones among
    m_L and theta_level are returned (within their boxes); {} when too few samples move."""
    free = {f.name: f for f in calib}
    if "m_L" not in free:
        return {}
    p = plant.vector()
    b = plant.boom
    sm = data.smooth
    x, v, a = sm["x"], sm["v"], sm["a"]
    x_end = float(stroke_end(plant.cylinder.x_max, b.theta_max, b.L_1, b.L_2, b.L_3))
    moving = (np.abs(v) > settings.commissioning_min_speed) & (x > 0.01) & (x < x_end - 0.01)
    if np.count_nonzero(moving) < settings.commissioning_min_samples:
        return {}
    x, v, a = x[moving], v[moving], a[moving]
    c = cos_joint_angle(x, b.L_1, b.L_2, b.L_3)
    s = np.sqrt(1.0 - c * c)
    r = torque_arm(x, b.L_1, b.L_2, b.L_3)
    slope = torque_arm_slope_cs(x, c, r, b.L_1, b.L_2, b.L_3)
    A_A = math.pi * plant.cylinder.D_piston ** 2 / 4
    A_B = A_A - math.pi * plant.cylinder.D_rod ** 2 / 4
    force = sm["pA"][moving] * A_A - sm["pB"][moving] * A_B
    X = np.column_stack([(a - slope * v * v / r ** 2) / r, c, s, r * np.sign(v), r * v])
    y = r * force
    keep = np.ones(len(y), bool)
    for _ in range(2):  # least squares, then again without the worst-fitting samples (start-ups, stops)
        coef, *_ = np.linalg.lstsq(X[keep], y[keep], rcond=None)
        e = y - X @ coef
        keep = np.abs(e) < 3.0 * np.std(e[keep])
    C = complex(coef[1], coef[2])
    w = p[P.m_B] * G * p[P.r_B] * complex(math.cos(-p[P.cog_angle]), math.sin(-p[P.cog_angle]))
    out = {}
    if "theta_level" in free:
        disc = abs(C) ** 2 - w.imag ** 2
        load_torque = -w.real + math.sqrt(max(disc, 0.0))  # m_L g L
        theta_level = math.remainder(math.atan2(C.imag, C.real) - math.atan2(w.imag, load_torque + w.real), 2 * math.pi)
        out["theta_level"] = theta_level
    else:
        # the level is known: project the gravity torque on the load's own direction
        theta_level = b.theta_level
        e = complex(math.cos(theta_level), math.sin(theta_level))
        load_torque = ((C - w * e) * e.conjugate()).real
    out["m_L"] = load_torque / (G * b.L)
    return {k: float(min(max(v, free[k].lo), free[k].hi)) for k, v in out.items()}


def commissioning_start(data: Prepared, plant: Plant, calib: tuple[Free, ...], settings: Settings) -> dict[str, float]:
    """The calibration's values at the plant's nominal ones, with the load and the level angle where
    the force balance puts them (:func:`force_balance_start`): where a calibration, or a hypothesis
    fitted with it, may start besides the calibrated values."""
    model = Model(plant.vector(), calib)
    return {**model.values_of(model.theta_of({})), **force_balance_start(data, plant, calib, settings)}


def calibrate(split: Split, plant: Plant, calib: tuple[Free, ...], start: dict[str, float],
              settings: Settings) -> FitResult:
    """Least squares on simulation error over ``calib`` with one residual variance per segment
    (:func:`fitting.fit_by_segment`), from the nominal values and from ``start``
    (:func:`commissioning_start`), whichever fits better at the start.

    The calibration is kept only when it predicts the held-out part better than the nominal values
    do (smaller squared error there); otherwise the nominal values are the calibration. A
    calibration that fits the fitting part but loses held out has fitted what the commissioning
    parameters cannot explain (a concealed effect, start transients), and every hypothesis would
    then be judged against, and start from, that distortion."""
    model = Model(plant.vector(), calib)
    nominal = model.theta_of({})
    cal = fit_by_segment(split, model, [nominal, model.theta_of(start)], settings.calibration_nfev,
                         settings.segment_rounds, settings.segment_round_nfev)
    kept = at(split, model, nominal)
    return cal if cal.rss_held < kept.rss_held else kept


__all__ = ["ALWAYS", "calibrate", "calibration_params", "commissioning_start", "force_balance_start"]
