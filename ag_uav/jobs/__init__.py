"""Many flights: batches, executors (local pool, dask), tuning, benchmarks, one logged run, and the
paper's experiments."""
