"""The domain model and pure solvers: arrays in, arrays out; no I/O, no bus."""
