"""The per-effect proof (docs/mismatch.md) at reduced size (12 s recordings): marked slow,
and run by CI with the rest of the suite; ``pytest -m "not slow"`` skips it while developing.

Each case hides one effect (or two, or none, or one outside the library) in a
recording made with ``sam``; the diagnosis runs blind with the nominal plant.
"""

from __future__ import annotations

import pytest

import sam
from discrepancy import diagnose
from discrepancy.cases import CASES, make_recording
from discrepancy.proof import score

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_case_is_diagnosed(case):
    rec = make_recording(case, duration=12.0, seed=7).measured()
    rep = diagnose(rec, sam.load_plant(), None, figures=False)
    r = score(case, rep)
    assert r["ok"], (rep.verdict, rep.named, rep.headline)
    if case.expect:
        assert r["held_after"] > r["held_cal"]
