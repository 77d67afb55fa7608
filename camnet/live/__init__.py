"""The live policy: warm re-solves as tracks come in, moved cameras, and when a solve may replace the last good one."""
