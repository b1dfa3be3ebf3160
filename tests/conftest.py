"""Test-wide settings: every hypothesis draw is seeded (derandomized), so a run is repeatable."""

from hypothesis import settings

settings.register_profile("seeded", derandomize=True, deadline=None)
settings.load_profile("seeded")
