"""The fleet layer: fleet files, the router configuration and the key expressions (above the pure core)."""
