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
    rule = _rule("an integer", minimum, maximum, None)

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {rule}, got {text!r}") from None
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"expected {rule}, got {text!r}")
        return value

    parse.__name__ = "integer"  # argparse names the type in its own messages
    return parse


def real(minimum: float | None = None, maximum: float | None = None, *,
         above: float | None = None) -> Callable[[str], float]:
    """An argparse type: a finite number within [minimum, maximum], and > ``above`` if given."""
    rule = _rule("a finite number", minimum, maximum, above)

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {rule}, got {text!r}") from None
        if (not math.isfinite(value) or (minimum is not None and value < minimum)
                or (maximum is not None and value > maximum) or (above is not None and not value > above)):
            raise argparse.ArgumentTypeError(f"expected {rule}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


def _rule(what: str, minimum, maximum, above) -> str:
    parts = [what]
    if above is not None:
        parts.append(f"> {above:g}")
    if minimum is not None:
        parts.append(f">= {minimum:g}")
    if maximum is not None:
        parts.append(f"<= {maximum:g}")
    return " ".join(parts[:1]) + (" " + " and ".join(parts[1:]) if len(parts) > 1 else "")
