"""Command-line tools of uav-flock: simulation runs, paper figures, plots."""
