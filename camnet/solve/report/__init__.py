"""What a solve reports of itself: the SolveReport (uncertainty, per-camera statistics,
warnings), what the scale rests on, and the verdict."""
