"""``gap-validate``, the command line (argparse): :mod:`~gap_validation.cli.main` parses and dispatches, one
module per subcommand (``replay``, ``compare_models``, ``simulate``, ``report``)."""
