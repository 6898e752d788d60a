"""The node graph of ``cartpole run``: its spec, its processes, the run monitor and the recorder node."""
