"""Ground station: station node, mission planner, backhaul, GCS gateway."""
