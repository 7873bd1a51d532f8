"""The model checker (``zdrone check``): bounded, exhaustive exploration of the authority protocol's
decisions with every attacker's moves (``abstract``), of operator consent (``consent``) and of the
shipped drone and GS cores in memory (``cores``); ``search`` is the breadth-first search they share,
``run`` picks the world and prints the result."""
