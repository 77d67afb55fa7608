"""Simulated rigs: scenes, ground-truth cameras, observations and rendered images."""
