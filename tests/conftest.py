"""Test-wide settings: every hypothesis draw is seeded (derandomized), so a run is repeatable."""

import pytest
from hypothesis import settings
from matplotlib.figure import Figure

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
