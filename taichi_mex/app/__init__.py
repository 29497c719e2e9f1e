"""The command line and the jobs, sweeps, studies and benchmarks it starts: the only
layer that parses arguments or prints."""
