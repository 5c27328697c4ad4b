"""One module per ``gap-validate`` subcommand: ``register(subparsers)`` and ``run(args) -> int``."""
