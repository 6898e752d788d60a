"""One module a `cartpole` subcommand: ``add_arguments(parser)`` and ``main(args)``."""
