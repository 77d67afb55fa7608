"""The domain model: cameras, observations, known distances, a frozen Calibration with its typed SolveReport;
projection and lens models, two-view geometry, triangulation, resection and the paper's solver, as pure
functions on arrays. Imports nothing else of camnet."""
