"""The verdict and the headline sentence of a diagnosis, from what :func:`diagnose.diagnose` found."""

from __future__ import annotations

from . import locate as loc


#: a calibration explains a mismatch only when it moves a value by more than this share of its
#: nominal value (494 -> 494.02 kg is no mis-set load) ...
RELATIVE_CHANGE = 0.05
#: ... or, for a value whose nominal is 0 (the offset, a fraction of spool travel), by this much
ABSOLUTE_CHANGE = 0.002


def _significant_change(c: dict) -> bool:
    if c["relative"]:
        return abs(c["change"]) > RELATIVE_CHANGE
    nominal = abs(c["nominal"])
    return abs(c["change"]) > (RELATIVE_CHANGE * nominal if nominal else ABSOLUTE_CHANGE)


def few(values, unit: str = "", shown: int = 5, fmt: str = "{:.0f}") -> str:
    """A list an engineer can read: all of up to ``shown`` values, else the first few and how many more."""
    words = [fmt.format(v) for v in values]
    more = f" and {len(words) - shown} more" if len(words) > shown else ""
    return f"{', '.join(words[:shown])}{unit}{more}"


def unscored_note(name: str, starts_s, n_segments: int, shift_s: float) -> str:
    """One plain sentence on the segments not scored because the oil is trapped at null."""
    return (f"{len(starts_s)} of {n_segments} segments of {name} (starting at t = {few(starts_s, ' s')}) are not scored: the "
            f"valve sits at null with the oil trapped, so their error is set by the start state (a {1e3 * shift_s:.0f} "
            "ms shift changes it), not by the model")


def verdict_of(chosen, calibration, gen, table, located, shortfall) -> tuple[str, str]:
    """(verdict, headline): 'named' (``chosen``, a list of diagnose.Candidate), 'unknown_effect' (the
    generic route's significant term ``gen``, or a calibrated model far short of its noise ceiling:
    ``shortfall`` from diagnose), 'recalibrated' / 'adequate' (a calibrated held-out fit >= 80 %, with or
    without a significant change of a commissioning value in ``calibration``), else 'unexplained'.
    ``table``: model -> part -> signal -> fit % (diagnose's fit table); ``located``: where the residual is."""
    changed = [c for c in calibration if _significant_change(c)]
    recal = ("after recalibrating " + ", ".join(c["text"] for c in changed)) if changed else "with the nominal parameters"
    cal_h = table["calibrated"]["held"]["mean"]
    where = _where_words(located)
    if chosen:
        c = chosen[0]
        aug = table["augmented"]["held"]["mean"]
        names = " and ".join(h.title for h in c.hypothesis)
        head = (f"{where}: that is {names}; with {c.summary()} the held-out fit goes from "
                f"{cal_h:.1f} % to {aug:.1f} % ({recal}).")
        return "named", head
    if gen and gen.get("significant"):
        return "unknown_effect", (
            f"{where}. No effect of the library explains it; the generic route finds {gen['equation']} "
            f"({gen['mapped']}), raising the held-out fit from {cal_h:.1f} % to {gen['fit_table']['held']['mean']:.1f} %.")
    if shortfall.get("short"):
        best = f"; the generic route's best term, {gen['equation']}, is not significant" if gen and gen.get("terms") else ""
        return "unknown_effect", (
            f"{where}. No effect of the library explains it: the calibrated model's held-out fit {cal_h:.1f} % errs "
            f"{shortfall['excess']:.1f} times the recording's noise (ceiling {shortfall['ceiling_held']['mean']:.1f} %; "
            f"clean recordings at most {shortfall['limit']:g} times){best}.")
    if cal_h >= 80.0:
        if changed:
            return "recalibrated", (f"The model is adequate {recal}: the mismatch was a mis-set nominal value, "
                                    f"not missing physics (held-out fit {cal_h:.1f} %).")
        return "adequate", f"The model is adequate: no candidate effect improves the fit (held-out fit {cal_h:.1f} %)."
    return "unexplained", (f"{where}, but neither the library nor the generic route explains it "
                           f"(held-out fit {cal_h:.1f} % {recal}).")


def _where_words(located) -> str:
    share = located["signal_share"]
    top = max(share, key=share.get)
    words = loc.SIGNAL_WORDS[top]
    regs = [r for r in located["regimes"] if r["enrichment"] > 1.3][:2]
    if regs:
        words += " is off mostly in " + " and ".join(
            f"{r['regime']} ({100 * r['residual_share']:.0f} % of the error in {100 * r['time_share']:.0f} % of the time)"
            for r in regs)
    else:
        words += " is off throughout the recording"
    return words[0].upper() + words[1:]


__all__ = ["few", "unscored_note", "verdict_of"]
