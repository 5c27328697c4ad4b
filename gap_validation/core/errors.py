"""Exceptions of gap_validation: one clear line each, naming the problem."""


class GapValidationError(Exception):
    """Base class; ``str(err)`` is a single line suitable for the terminal.

    Parameters
    ----------
    *args : object
        As for :class:`Exception`; a single message string has its line breaks escaped.
    """

    exit_code = 1

    def __init__(self, *args: object) -> None:
        # names from files (keys, topics, values) may hold line breaks: keep the message on one line
        if len(args) == 1 and isinstance(args[0], str):
            args = (args[0].replace("\r", "\\r").replace("\n", "\\n"),)
        super().__init__(*args)


class ConfigError(GapValidationError, ValueError):
    """Bad configuration or usage: names the file, key and value (CLI exit status 2)."""

    exit_code = 2


class DataError(GapValidationError):
    """Unreadable or unusable data: names the file or topic (CLI exit status 1)."""

    exit_code = 1


def one_line(err: BaseException) -> str:
    """The text of an exception on one line (whitespace collapsed, no trailing period), or its type name.

    Parameters
    ----------
    err : BaseException
        Any exception.
    """
    text = " ".join(str(err).split()) or type(err).__name__
    return text.rstrip(".")
