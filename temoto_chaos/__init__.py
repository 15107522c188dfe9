"""Chaos: a seeded history of client operations and faults against the real managers, checked after every
step by a checker that reads the system from outside (registries as JSON, processes from the kernel)."""
