"""Registration of the node subcommands (router, sim, drone, gs, demo, report)."""
