"""Docstrings of the core, in the manner of python-control's ``control/tests/docstrings_test.py``.

Every public function, class, method and property of :mod:`gap_validation.core` has a docstring; every
function or method with parameters has a numpydoc ``Parameters`` section that names each of them (a class
documents its constructor's parameters in its own docstring, under ``Parameters`` or, for a dataclass,
``Attributes``).
"""
from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re

import pytest

import gap_validation.core

MODULES = sorted(m.name for m in pkgutil.iter_modules(gap_validation.core.__path__, "gap_validation.core."))
_SECTION = re.compile(
    r"^(\s*)(Parameters|Attributes|Other Parameters)\n\1-{3,}\n(.*?)(?=^\s*\S[^\n]*\n\s*-{3,}\n|\Z)",
    re.M | re.S,
)
_NAMES = re.compile(r"^(\s*)(\*{0,2}[A-Za-z_][\w, *]*?)\s*(?::|$)", re.M)


def _documented(doc: str, sections: tuple[str, ...] = ("Parameters", "Other Parameters")) -> set[str] | None:
    """Names documented in the ``sections`` of a numpydoc docstring (None when there is no such section)."""
    found = None
    for match in _SECTION.finditer(inspect.cleandoc(doc) + "\n"):
        if match.group(2) not in sections:
            continue
        found = found or set()
        body = match.group(3)
        indent = min(
            (len(line) - len(line.lstrip()) for line in body.splitlines() if line.strip()), default=0
        )
        for line in body.splitlines():
            if line.strip() and len(line) - len(line.lstrip()) == indent:
                head = line.split(" : ")[0].strip()
                found.update(name.strip().lstrip("*") for name in head.split(","))
    return found


def _parameters(func) -> list[str]:
    try:
        signature = inspect.signature(func)
    except (TypeError, ValueError):
        return []
    return [name for name in signature.parameters if name not in ("self", "cls") and not name.startswith("_")]


def _public(module) -> list[tuple[str, object]]:
    out = []
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
            continue
        if inspect.isfunction(obj) or inspect.isclass(obj):
            out.append((name, obj))
    return out


def _members(cls) -> list[tuple[str, object]]:
    out = []
    for name, obj in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(obj, (staticmethod, classmethod)):
            obj = obj.__func__
        if inspect.isfunction(obj) or isinstance(obj, property):
            out.append((name, obj))
    return out


def _problems(where: str, obj, doc_of_params: str | None = None, sections=("Parameters", "Other Parameters")):
    doc = inspect.getdoc(obj) if not isinstance(obj, property) else obj.__doc__
    if not doc or not doc.strip():
        return [f"{where}: no docstring"]
    if isinstance(obj, property) or inspect.isclass(obj):
        return []
    names = _parameters(obj)
    if not names:
        return []
    documented = _documented(doc_of_params or doc, sections)
    if documented is None:
        return [f"{where}: no Parameters section for {', '.join(names)}"]
    missing = [n for n in names if n not in documented]
    return [f"{where}: parameter {n} not documented" for n in missing]


def _class_problems(module_name: str, name: str, cls) -> list[str]:
    where = f"{module_name}.{name}"
    problems = _problems(where, cls)
    init = vars(cls).get("__init__")
    if init is not None and inspect.isfunction(init) and not dataclasses.is_dataclass(cls):
        problems += _problems(f"{where}()", init, doc_of_params=inspect.getdoc(cls) or "")
    for member_name, member in _members(cls):
        problems += _problems(f"{where}.{member_name}", member)
    return problems


@pytest.mark.parametrize("module_name", MODULES)
def test_public_definitions_have_numpydoc_docstrings(module_name):
    module = importlib.import_module(module_name)
    assert module.__doc__ and module.__doc__.strip(), f"{module_name}: no module docstring"
    problems = []
    for name, obj in _public(module):
        if inspect.isclass(obj):
            problems += _class_problems(module_name, name, obj)
        else:
            problems += _problems(f"{module_name}.{name}", obj)
    assert not problems, "\n".join(problems)


#: Modules whose every function, private ones too, is annotated; the others' public definitions are.
FULLY_ANNOTATED = (
    "gap_validation.core.metrics",
    "gap_validation.core.models",
    "gap_validation.core.effects",
    "gap_validation.core.numbers",
    "gap_validation.core.layouts",
    "gap_validation.core.results",
    "gap_validation.core.margins",
)


def _functions(module, private: bool):
    for name, obj in vars(module).items():
        if getattr(obj, "__module__", None) != module.__name__ or (name.startswith("_") and not private):
            continue
        if inspect.isfunction(obj):
            yield f"{module.__name__}.{name}", obj
        elif inspect.isclass(obj) and not dataclasses.is_dataclass(obj):
            for member_name, member in vars(obj).items():
                if isinstance(member, (staticmethod, classmethod)):
                    member = member.__func__
                if isinstance(member, property):
                    member = member.fget
                if inspect.isfunction(member) and (private or not member_name.startswith("_")
                                                   or member_name == "__init__"):
                    yield f"{module.__name__}.{name}.{member_name}", member


@pytest.mark.parametrize("module_name", MODULES)
def test_core_functions_have_type_hints(module_name):
    module = importlib.import_module(module_name)
    problems = []
    for where, func in _functions(module, private=module_name in FULLY_ANNOTATED):
        signature = inspect.signature(func)
        bare = [n for n, p in signature.parameters.items() if n not in ("self", "cls")
                and p.annotation is inspect.Parameter.empty]
        if bare:
            problems.append(f"{where}: no type hint for {', '.join(bare)}")
        if signature.return_annotation is inspect.Signature.empty:
            problems.append(f"{where}: no return type hint")
    assert not problems, "\n".join(problems)


def test_the_checker_sees_parameters_and_their_absence():
    def documented(a, b=1):
        """Sum.

        Parameters
        ----------
        a, b : int
            Terms.
        """

    def undocumented(a, c):
        """Sum.

        Parameters
        ----------
        a : int
            Term.
        """

    assert _problems("documented", documented) == []
    assert _problems("undocumented", undocumented) == ["undocumented: parameter c not documented"]
    assert _problems("bare", lambda x: x) == ["bare: no docstring"]


#: Every package's public face (``__all__`` of its ``__init__``): the numpydoc check beyond the core.
FACES = ["gap_validation"] + sorted(f"gap_validation.{m.name}" for m in pkgutil.iter_modules(
    importlib.import_module("gap_validation").__path__) if m.ispkg)


@pytest.mark.parametrize("package", FACES)
def test_every_public_name_of_every_package_has_numpydoc_docstrings(package):
    if package in ("gap_validation.ros", "gap_validation.jsbsim"):
        pytest.importorskip("rclpy" if package.endswith("ros") else "jsbsim")
    face = importlib.import_module(package)
    problems = []
    for name in face.__all__:
        obj = getattr(face, name)
        where = f"{package}.{name}"
        if inspect.isclass(obj):
            problems += _class_problems(package, name, obj)
        elif inspect.isfunction(obj):
            problems += _problems(where, obj)
    assert not problems, "\n".join(problems)
