"""`cartpole` subcommands of the tools, found by the CLI through the `cartpole.commands` entry points."""
