"""Test-wide settings: every hypothesis draw is seeded (derandomized), so a run is repeatable;
the tests' own cached numba kernels are stamped by what they import (sam.jitcache)."""

from pathlib import Path

import pytest
from hypothesis import settings
from matplotlib.figure import Figure

from sam import jitcache

# tests/test_model_step.py and test_kernel_lanes.py compile sam's step and its constants into
# kernels of their own: keyed by their file alone they ran stale after sam's parameter vector grew
jitcache.register_folder(Path(__file__).resolve().parent)

settings.register_profile("seeded", derandomize=True, deadline=None)
settings.load_profile("seeded")


@pytest.fixture
def saved_figures(monkeypatch) -> list[Figure]:
    """Every matplotlib Figure saved while the test runs, in order, kept to look at."""
    saved, save = [], Figure.savefig

    def keep(fig, *args, **kwargs):
        saved.append(fig)
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return saved
