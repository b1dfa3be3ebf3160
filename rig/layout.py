"""The rig's layouts: its state vector (:class:`R`), its machine vector (:class:`C`), and the
physical constants its equations use.

The rig's own state, chosen apart from sam's (Eq. (18)): the boom's joint angle and rate rather
than the piston's position and velocity, and the oil each chamber holds rather than its pressure
(a pressure follows from the oil and the chamber's volume, :func:`rig.hydraulics.chamber_pressure`).
"""

from __future__ import annotations

from enum import IntEnum


class R(IntEnum):
    """Index of each state of the rig."""

    theta = 0  #: rad, joint angle (Eq. (3)'s theta)
    omega = 1  #: rad/s, its rate
    oil_A = 2  #: m^3, oil in chamber A and its hose, as its volume at atmospheric pressure
    oil_B = 3  #: m^3, ... chamber B
    x_s = 4  #: 1, spool position, fraction of full travel
    w_s = 5  #: 1/s, spool velocity
    z = 6  #: m, LuGre bristle deflection
    air_A = 7  #: 1, free air in chamber A per unit oil, at atmospheric pressure
    air_B = 8  #: 1, ... chamber B
    oil_S = 9  #: m^3, oil in the supply line (a pump-limited supply)
    y_A = 10  #: Pa, transmitter A's output (with a transmitter lag)
    y_B = 11  #: Pa, transmitter B's output


N_STATE = len(R)

G = 9.81  #: m/s^2
P_ATM = 101_325.0  #: Pa, atmospheric pressure: gauge pressures are relative to it
P_VAPOUR = 2_000.0 - P_ATM  #: Pa (gauge), oil's vapour pressure: a chamber below it holds a void
KAPPA = 1.4  #: 1, polytropic exponent of free air in fast transients


class C(IntEnum):
    """Index of each constant of the rig's machine vector."""

    # boom, Eqs. (3)-(5), (16), contract C1
    L_1 = 0
    L_2 = 1
    L_3 = 2
    L = 3  #: m, load distance
    r_B = 4  #: m, boom's centre of gravity from the joint
    theta_level = 5  #: rad, joint angle at which the boom is level
    cog_angle = 6  #: rad, direction of the boom's centre of gravity from the m_L arm
    m_B = 7
    m_L = 8  #: kg, time-varying
    m_R = 9
    J_fixed = 10  #: kg m^2, boom (m_B L_B^2 / 12), m_R L^2 and extra inertia
    gyration_sq = 11  #: m^2, L^2 + load gyration radius^2: J of the left load per kg
    x_end = 12  #: m, extension end stop (stroke or joint limit)
    # cylinder and hoses
    A_A = 13
    A_B = 14
    V_0A = 15
    V_0B = 16
    x_max = 17
    hose_A = 18
    hose_B = 19
    hose_modulus = 20
    # oil and air
    B = 21  #: Pa, bulk modulus of the oil itself
    air_content = 22
    air_dissolved = 23
    air_tau = 24
    # valve, Eqs. (10)-(15)
    K_PA = 25
    K_AT = 26
    K_PB = 27
    K_BT = 28
    lap_PA = 29
    lap_AT = 30
    lap_PB = 31
    lap_BT = 32
    KL_PA = 33  #: m^3/(s Pa), laminar null leakage, Eqs. (13)-(14)
    KL_AT = 34
    KL_PB = 35
    KL_BT = 36
    leak_band = 37
    K_u = 38
    omega_n = 39
    zeta = 40
    notch_knee = 41
    notch_exponent = 42
    stiction = 43
    dp_laminar = 44
    offset = 45  #: time-varying
    # leaks, Eqs. (41)-(43), and the bypass
    K_int = 46  #: time-varying
    K_extA = 47  #: time-varying
    K_extB = 48  #: time-varying
    bypass = 49
    # supply
    p_S = 50
    p_T = 51
    pump = 52  #: m^3/s; inf: ideal source
    relief_crack = 53
    relief_gain = 54
    V_line = 55
    # friction, Eq. (17), and the seals
    F_C = 56
    F_S = 57
    v_s = 58
    sigma_0 = 59
    b = 60
    seal_piston = 61
    seal_rod = 62
    # end stops, transmitters
    k_stop = 63
    stop_damping = 64  #: s/m, Hunt-Crossley alpha
    lag = 65  #: s, transmitter lag (0: none)
    spool_stuck = 66  #: 1.0 while the spool sticks (set by the integrator)
    reduced_mass_motion = 67  #: 1.0: the boom moves as Eq. (19) says, without Eq. (7)'s R-dot term
    leak_taper = 68  #: 1, the outer fraction of the null-leakage band over which it fades
    spool_sliding = 69  #: 1, a sticking spool's sliding friction as a share of its breakaway
    port = 70  #: m^3/(s Pa^0.5), a fixed restriction in series with each metering edge (inf: none)
    full_area = 71  #: 1, the open fraction at which a notch has uncovered its whole port (1: full travel)


N_CONSTANTS = len(C)

#: The scenario's time-varying parameters the rig follows, by their sam name.
TIME_VARYING = {"K_int": C.K_int, "K_extA": C.K_extA, "K_extB": C.K_extB, "offset": C.offset, "m_L": C.m_L}


