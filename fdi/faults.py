"""The faults the tool looks for, and the names every stage uses for them.

Four fault parameters, each a state of the filter: the internal leak K_int, the external
leaks K_extA and K_extB (m^3/(s Pa^0.5), reported in L/min at 10 MPa) and the spool offset
(fraction of spool travel). The change tests watch five hypotheses (the offset either way);
the likelihood bank compares "none", each single fault and each pair.
"""

from __future__ import annotations

from .states import I_KEXTA, I_KEXTB, I_KINT, I_OFFSET, leak_lpm

#: Fault parameter -> its filter state.
PARAMS = {"K_int": I_KINT, "K_extA": I_KEXTA, "K_extB": I_KEXTB, "offset": I_OFFSET}
#: Change-test hypothesis -> (the state it reads, +1 above healthy / -1 below).
HYPOTHESES = {"K_int": (I_KINT, +1), "K_extA": (I_KEXTA, +1), "K_extB": (I_KEXTB, +1),
              "offset+": (I_OFFSET, +1), "offset-": (I_OFFSET, -1)}
#: The alarm source that is no fault hypothesis: a jump of the filter's notch-flow states.
NOTCH_TRIGGER = "notch_flow"
#: The filter's calibration states the notch-flow trigger watches: the valve notches' flows.
NOTCH_STATES = ("Q_N_PA", "Q_N_AT", "Q_N_PB", "Q_N_BT")
#: Operating regimes of the change test, from the valve input u: "hold" |u| below the band,
#: extension / retraction beyond it, "transient" for the first seconds of a direction.
REGIMES = ("hold", "extend-transient", "extend-steady", "retract-transient", "retract-steady")

#: Likelihood-bank hypothesis -> the state it leaves free (None: the healthy hypothesis).
BANK = {"none": None, **PARAMS}
FAULTS = tuple(PARAMS)
#: Separator of a pair hypothesis' name: "K_int+K_extB" has both parameters free.
PAIR_SEP = "+"
#: Pair hypotheses: name -> the two states left free (every unordered pair of FAULTS).
PAIRS = {f"{a}{PAIR_SEP}{b}": (BANK[a], BANK[b]) for i, a in enumerate(FAULTS) for b in FAULTS[i + 1:]}
#: Hypotheses of the several-faults stage: the four single faults, then the six pairs.
MULTI = FAULTS + tuple(PAIRS)


def free_states(name: str) -> tuple:
    """The state indices a bank hypothesis leaves free: () for "none", one for a single fault
    (a BANK name), two for a pair ("A+B", a PAIRS name, in either order)."""
    if name in BANK:
        return () if BANK[name] is None else (BANK[name],)
    parts = name.split(PAIR_SEP)
    if len(parts) != 2 or not all(p in FAULTS for p in parts) or parts[0] == parts[1]:
        raise ValueError(f"unknown bank hypothesis {name!r}: a name of BANK or 'A{PAIR_SEP}B' with A, B in {FAULTS}")
    return tuple(BANK[p] for p in parts)


def hypothesis_name(param: str, change: float) -> str:
    """The HYPOTHESES name of a fault parameter that changed by ``change``: the offset's side
    from its sign."""
    if param != "offset":
        return param
    return "offset+" if change >= 0 else "offset-"


def size_entry(name: str, m: float, s: float) -> dict:
    """The size of a change m +- 2 s (SI) of hypothesis ``name``, as diagnosis.json reports it:
    leaks in L/min at 10 MPa (with the coefficient itself), the offset in % of spool travel."""
    if name.startswith("K_"):
        return {"value": float(leak_lpm(m)), "minus_2sigma": float(leak_lpm(m - 2 * s)),
                "plus_2sigma": float(leak_lpm(m + 2 * s)), "unit": "L/min at 10 MPa", "K_m3_per_s_sqrtPa": m}
    return {"value": 100 * m, "minus_2sigma": 100 * (m - 2 * s), "plus_2sigma": 100 * (m + 2 * s),
            "unit": "% of spool travel"}
