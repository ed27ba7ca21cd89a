"""Many episodes: the parallel, resumable runner and its record store, experiments, sweeps
and the benchmarks."""
