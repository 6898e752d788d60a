"""A third-party stabiliser plugin for the cartpole controller manager: pole placement."""
