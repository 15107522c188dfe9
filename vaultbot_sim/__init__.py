"""Simulated VaultBot: world, robot state, device cables and sensor drivers."""
