"""Learned control on the project's plant: gymnasium environment, trainer, ``policy`` plugin."""
