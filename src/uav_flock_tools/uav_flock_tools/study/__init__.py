"""Studies: many runs of a grid of layouts, seeds, kinds of motion and variants, as Dask tasks, into one
Parquet table (`uav-flock study`, docs/studies.md)."""
