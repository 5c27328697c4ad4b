"""Load and write validation configs (YAML). The schema lives in :mod:`gap_validation.core.config`."""
from __future__ import annotations

import os
from pathlib import Path

import yaml

from gap_validation.atomic import atomic_write_text
from gap_validation.core.config import ValidationConfig, parse_config
from gap_validation.core.errors import ConfigError, DataError

__all__ = ["load_config", "dump_config", "read_yaml", "ValidationConfig"]


def load_config(path: str | os.PathLike) -> ValidationConfig:
    """Read a validation config file.

    Raises
    ------
    ConfigError
        One line naming the file and the problem (missing file, YAML syntax with line number, bad key).
    """
    path = Path(path)
    return parse_config(read_yaml(path, "config file", "config"), str(path))


def read_yaml(path: str | os.PathLike, what: str, short: str | None = None):
    """The YAML document of a file (configs, campaign manifests), or a one-line :class:`ConfigError`.

    ``what`` names the kind of file in the messages (``"config file"``: "config file not found", "is a directory,
    not a config file"); ``short`` in "cannot read <short>" (default ``what``).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not a text (UTF-8) file (byte {err.start}: {err.reason})") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a {what}") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read {short or what} ({err.strerror or err})") from None
    try:
        return yaml.safe_load(text)
    except RecursionError:
        raise ConfigError(f"{path}: YAML error: nested too deeply") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or "invalid YAML"
        raise ConfigError(f"{path}: YAML error{where}: {problem}") from None


def dump_config(config: ValidationConfig | dict, path: str | os.PathLike) -> None:
    """Write a config (its raw mapping) as YAML, atomically (:mod:`gap_validation.atomic`: temporary file, then
    rename; a crash never leaves a half-written config).

    Raises
    ------
    DataError
        One line naming the file when it cannot be written (the old file, if any, is kept).
    """
    data = config.raw if isinstance(config, ValidationConfig) else config
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    try:
        atomic_write_text(path, text)
    except OSError as err:
        raise DataError(f"{path}: cannot write config ({err.strerror or err})") from None
