"""The nodes: the drone companion (here) and the ground station (the top-level ``gs`` package)."""
