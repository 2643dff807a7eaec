"""Writers and readers of trajectory files: C3D, TRC, CSV, MCAP."""
