"""Where a solve starts: from nothing (the scale pair, then the view graph), from the paper's solver,
or from a previous calibration; and which start to keep."""
