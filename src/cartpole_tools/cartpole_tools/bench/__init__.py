"""The benchmarks of ``cartpole bench``: controller comparison, loop latency, robustness, the sweep runner."""
