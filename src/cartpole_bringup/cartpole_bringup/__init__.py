"""The `cartpole` command: starts the node graph, records bags, analyses runs, benchmarks."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
