"""Test-wide settings: hypothesis without per-example deadlines (CI machines are shared and loaded;
speed targets live in ``zdrone bench``, not in timed tests)."""

from hypothesis import settings

settings.register_profile("zdrone", deadline=None)
settings.load_profile("zdrone")
