"""TeMoto Sensor Manager: sensors as ranked, failing-over resources."""
