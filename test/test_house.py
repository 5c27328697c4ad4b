"""The house's two structural rules (issue 27), checked on the source:

- **No private name crosses a module boundary.** A module neither imports another's ``_name`` nor reads or
  calls ``something._name`` unless ``_name`` is defined in that same module (a function, class, attribute or
  variable it assigns): what one module needs of another is public, with a docstring. namedtuple's own API
  (``_replace``, ``_asdict``, ``_fields``, ``_make``) is public despite its underscore.
- **No import cycle** among the package's modules, counting imports inside functions and under
  ``TYPE_CHECKING`` (a cycle hidden in a function is still a cycle: the two modules cannot be read apart).

Both checks are shown to fail on a planted violation, so a clean run means something.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "gap_validation"

#: Underscore names that are a public API (namedtuple's).
PUBLIC_UNDERSCORE = {"_replace", "_asdict", "_fields", "_make", "_field_defaults"}


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_crossings(source: str, where: str) -> list[str]:
    """Every private name one module takes from another: ``from m import _x`` and ``obj._x`` where ``_x`` is
    not defined in the module itself."""
    tree = ast.parse(source)
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            own.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            own.add(node.id)
        elif isinstance(node, ast.arg):
            own.add(node.arg)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            out += [f"{where}:{node.lineno}: from {node.module} import {a.name}" for a in node.names
                    if _private(a.name)]
        elif isinstance(node, ast.Attribute) and _private(node.attr) and node.attr not in own \
                and node.attr not in PUBLIC_UNDERSCORE:
            out.append(f"{where}:{node.lineno}: {ast.unparse(node)}")
    return out


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(files: dict[str, str]) -> dict[str, set[str]]:
    """Module -> the package's modules it imports anywhere in its source (``files``: module name ->
    source)."""
    graph: dict[str, set[str]] = {}
    for module, source in files.items():
        package = module if module + ".__init__" in files else module.rsplit(".", 1)[0]
        edges = set()
        for node in ast.walk(ast.parse(source)):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(parts + ([node.module] if node.module else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            edges |= {t for t in targets if t in files and t != module}
        graph[module] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (iterative Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def _sources() -> dict[str, str]:
    files = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        name = _module_name(path)
        files[name] = path.read_text()
        if path.name == "__init__.py":
            files[name + ".__init__"] = ""      # marks a package (relative imports resolve inside it)
    return files


def test_no_private_name_crosses_a_module_boundary():
    found = [line for path in sorted(PACKAGE.rglob("*.py"))
             for line in private_crossings(path.read_text(), str(path.relative_to(ROOT)))]
    assert not found, "\n".join(found)


def test_the_private_check_finds_a_planted_crossing():
    planted = ("from gap_validation.core.metrics import _strip\n"
               "class Topics:\n"
               "    def __init__(self, node):\n"
               "        self._own = node._param('x')\n"
               "        self._own._replace()\n")
    found = private_crossings(planted, "planted.py")
    assert [f.split(": ", 1)[1] for f in found] == ["from gap_validation.core.metrics import _strip",
                                                      "node._param"]


def test_no_import_cycle():
    found = cycles(import_graph(_sources()))
    assert not found, found


def test_the_cycle_check_finds_a_planted_cycle_inside_a_function():
    files = {"p": "", "p.__init__": "", "p.a": "from p.b import f\n",
             "p.b": "def f():\n    from p import c\n", "p.c": "from .a import g\n", "p.d": "import p.a\n"}
    assert cycles(import_graph(files)) == [["p.a", "p.b", "p.c"]]


PACKAGES = ["gap_validation"] + sorted(
    f"gap_validation.{p.parent.name}" for p in PACKAGE.glob("*/__init__.py")
)


def test_every_package_names_its_public_face_and_imports_it_only_when_used():
    """``__all__`` in each ``__init__``: every name resolves to what its module defines, and importing the
    package alone imports none of its modules (so ``gap_validation.ros`` stays free of rclpy until the node is
    used)."""
    import importlib
    import subprocess
    import sys

    for name in PACKAGES:
        package = importlib.import_module(name)
        assert package.__all__, name
        for public in package.__all__:
            assert getattr(package, public) is not None, f"{name}.{public}"
        assert set(package.__all__) <= set(dir(package)), name
    code = (
        "import sys, importlib\n"
        f"for name in {PACKAGES!r}:\n"
        "    before = set(sys.modules)\n"
        "    importlib.import_module(name)\n"
        "    new = {m for m in set(sys.modules) - before if m.startswith('gap_validation.')}\n"
        "    print(name, sorted(new - "
        "{name, 'gap_validation', 'gap_validation.core', 'gap_validation.core.exports'}))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert all(line.endswith(" []") for line in done.stdout.splitlines()), done.stdout
