"""Features, pairwise matches, tracks and the track pool: arrays and the model in, arrays out."""
