"""The wire: frame messages, key expressions, Zenoh sessions, frame-set sync, lockstep, node statistics, launching."""
