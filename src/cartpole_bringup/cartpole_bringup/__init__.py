"""The `cartpole` command: starts the node graph, records bags, analyses runs, benchmarks."""
