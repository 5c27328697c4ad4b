"""A package's public face, imported on first use (PEP 562).

Each package's ``__init__`` names what it offers in ``__all__`` and where each name lives; the name's module
is imported when the name is first used, not when the package is. So ``import gap_validation.ros`` still
imports no rclpy, and importing one module of the core does not import all of it.
"""
from __future__ import annotations

import importlib
from typing import Any, Callable

__all__ = ["lazy_exports"]


def lazy_exports(package: str, names: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for a package whose public names live in its modules.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : dict
        Public name -> the module (relative to ``package``, or absolute when it starts with
        ``gap_validation.``) that defines it.

    Returns
    -------
    (callable, callable)
        The package's ``__getattr__`` (AttributeError for any other name, as Python's own) and ``__dir__``.
    """
    def getattr_(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        full = module if module.startswith("gap_validation.") else f"{package}.{module}"
        return getattr(importlib.import_module(full), name)

    def dir_() -> list[str]:
        return sorted(set(names) | set(importlib.import_module(package).__dict__))

    return getattr_, dir_
