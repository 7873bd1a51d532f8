"""Pure, sans-IO core of zdrone.

Nothing in this package touches zenoh, sockets, threads, asyncio or clocks: time comes in as
``now`` (seconds, float) and results come out as values. A test enforces the rule.
"""
