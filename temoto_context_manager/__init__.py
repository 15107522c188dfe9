"""TeMoto Context Manager: trackers and tracked objects as ranked, failing-over resources (issue 6)."""
