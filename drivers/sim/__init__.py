"""Simulated devices and the simulated cell's one truth. Runtime code never imports this package."""
