"""Numbers a user types on the command line, checked once, at the edge.

Every numeric option of every command goes through :func:`integer` or
:func:`real`, used as an argparse ``type``: a bad value stops the command before
any work, with one line naming the option, the rule and the value
("argument --workers: expected an integer >= 1, got '0'"). NaN and infinity
are never a valid option.

    p.add_argument("--workers", type=integer(minimum=1))
    p.add_argument("--segment", type=real(above=0.0), default=1.0)
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def integer(minimum: int | None = None, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse type: a whole number within [minimum, maximum] (either may be open)."""
    return _typed(int, "integer", _rule("an integer", minimum, maximum, None),
                  lambda v: (minimum is None or v >= minimum) and (maximum is None or v <= maximum))


def real(minimum: float | None = None, maximum: float | None = None, *,
         above: float | None = None) -> Callable[[str], float]:
    """An argparse type: a finite number within [minimum, maximum], and > ``above`` if given."""
    return _typed(float, "number", _rule("a finite number", minimum, maximum, above),
                  lambda v: (math.isfinite(v) and (minimum is None or v >= minimum)
                             and (maximum is None or v <= maximum) and (above is None or v > above)))


def _typed(convert, name: str, rule: str, ok) -> Callable[[str], int | float]:
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            value = None
        if value is None or not ok(value):
            raise argparse.ArgumentTypeError(f"expected {rule}, got {text!r}")
        return value

    parse.__name__ = name  # argparse names the type in its own messages
    return parse


def _rule(what: str, minimum, maximum, above) -> str:
    limits = [f"{sign} {bound:g}" for sign, bound in ((">", above), (">=", minimum), ("<=", maximum))
              if bound is not None]
    return what + (" " + " and ".join(limits) if limits else "")
