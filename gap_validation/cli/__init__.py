"""``gap-validate``, the command line (argparse): :mod:`~gap_validation.cli.main` parses and dispatches, one
module per subcommand (``replay``, ``compare_models``, ``simulate``, ``report``)."""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "build_parser": "main"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
