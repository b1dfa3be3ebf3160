"""The per-effect proof (docs/mismatch.md) at reduced size: slow, run with ``pytest -m slow``.

Each case hides one effect (or two, or none, or one outside the library) in a
recording made with ``sam``; the diagnosis runs blind with the nominal plant.
"""

from __future__ import annotations

import pytest

import sam
from discrepancy import diagnose
from scenarios.mismatch.generate import CASES, make_recording
from scenarios.mismatch.proof import score

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def _only_when_selected(request):
    if "slow" not in (request.config.option.markexpr or ""):
        pytest.skip("slow: run with -m slow")


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_case_is_diagnosed(case):
    rec = make_recording(case, duration=12.0, seed=7).measured()
    rep = diagnose(rec, sam.load_plant(), None, figures=False)
    r = score(case, rep)
    assert r["ok"], (rep.verdict, rep.named, rep.headline)
    if case.expect:
        assert r["held_after"] > r["held_cal"]
