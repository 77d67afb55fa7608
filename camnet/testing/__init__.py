"""Helpers for tests and benchmarks only (free loopback ports, random tracks, a whole live rig solved once);
nothing shipped imports them."""
