"""The engineer's tools over the graph: benchmarks, plant identification and the README's generated reference tables, as `cartpole bench` and `cartpole identify`."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
