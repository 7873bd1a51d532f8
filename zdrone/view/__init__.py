"""``zdrone view``: the live web view of the fleet (``server``), and what a GS publishes for it (``publish``)."""
