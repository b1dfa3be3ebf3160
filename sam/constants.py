"""Physical constants and model conventions that are not plant parameters."""

G = 9.81  #: m/s^2, gravitational acceleration
P_ATM = 101_325.0  #: Pa, atmospheric pressure (gauge pressures are relative to it)
KAPPA_AIR = 1.4  #: 1, polytropic exponent of entrained air (adiabatic: fast transients)

#: Pa (gauge). Chamber pressures are clamped here: 1.325 kPa absolute, just above
#: the vapour pressure of mineral oil. Below it the fluid cavitates and Eqs. (8)-(9)
#: no longer hold, so a simulation that reaches it is flagged (see SimulationResult).
P_CAVITATION = 1_325.0 - P_ATM

DT_DEFAULT = 1e-3  #: s, the paper's Euler step T, Eq. (22)

#: Conversion of leak size conventions: 1 L/min at 10 MPa (Table 5's upper bound).
LPM = 1e-3 / 60.0  #: m^3/s per L/min
LEAK_REFERENCE_DP = 10e6  #: Pa, the pressure difference at which leaks are quoted in L/min
