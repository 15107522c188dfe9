"""TeMoto Sensor Manager: sensors as ranked, failing-over resources (DESIGN.md, issue 6)."""
