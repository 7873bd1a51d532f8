"""Measurements: ``zdrone bench ...`` and the flight report."""
