"""Many episodes: the parallel, resumable runner, its record store, experiments, sweeps and
the benchmarks."""
