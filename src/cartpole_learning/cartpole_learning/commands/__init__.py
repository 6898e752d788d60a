"""The ``cartpole.commands`` entry points of this package (``cartpole train``)."""
