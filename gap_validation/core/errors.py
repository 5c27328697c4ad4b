"""Exceptions of gap_validation: one clear line each, naming the problem."""


class GapValidationError(Exception):
    """Base class; ``str(err)`` is a single line suitable for the terminal."""

    exit_code = 1


class ConfigError(GapValidationError, ValueError):
    """Bad configuration or usage: names the file, key and value (CLI exit status 2)."""

    exit_code = 2


class DataError(GapValidationError):
    """Unreadable or unusable data: names the file or topic (CLI exit status 1)."""

    exit_code = 1
