"""monoguide calls no private API of a dependency: a private name of another library may change or go in any
release (tomlkit 0.15 dropped the ``Container._insert_after`` that the calibration file's writer called, and a
fresh install could no longer write a calibration).

The scan parses (``ast``) every module of the repository (solver/, drivers/, daemon/, tests/, benchmarks/, ...)
and reports, as a hit:

- ``x._name`` (not a dunder) where ``x`` is not ``self`` or ``cls`` and ``_name`` is no name monoguide defines
  anywhere: a function, method or class, a module or package, a module-level or class-level name, an attribute
  set on ``self`` or ``cls``;
- ``m._name`` where ``m`` (or the root of a dotted ``m.sub``) was imported from a dependency, whatever monoguide
  defines: ``os._exit`` is the os module's, not ours;
- ``from dependency import _name``, and ``import dependency._module``;
- ``getattr(x, "_name")`` and ``setattr``, ``hasattr``, ``delattr`` alike, as ``x._name``.

Each hit must be in :data:`ALLOWED`, with why it is public after all; a new one fails naming its file, line and
expression. Code inside strings (the scripts that tests run as child processes) is not parsed.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOT_OURS = {"build", "dist"}  # besides dot folders (.venv, .venv-newest, .git): what an install or a build leaves

# expression -> why it is public API after all
ALLOWED: dict[str, str] = {
    "os._exit": "documented in Python's os module (leave the process at once, no clean-up, no destructors): the UR "
                "worker leaves with it so the ur-rtde interface's destructor never runs",
}


@dataclass(frozen=True)
class Hit:
    """One use of a private name: where, and the expression as written (``ast.unparse``)."""

    path: str
    line: int
    expression: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.expression}"


def test_no_module_uses_a_private_name_of_a_dependency() -> None:
    unjustified = [hit for hit in repository_hits() if hit.expression not in ALLOWED]
    assert not unjustified, ("private API of a dependency (use its public API, or justify it in ALLOWED):\n"
                             + "\n".join(map(str, unjustified)))


def test_every_allowed_use_is_still_made() -> None:
    made = {hit.expression for hit in repository_hits()}
    assert not set(ALLOWED) - made, f"ALLOWED names uses that no module makes any more: {sorted(set(ALLOWED) - made)}"


def test_the_scan_reports_a_dependency_s_private_call_and_nothing_of_ours() -> None:
    ours = "def _exit() -> None: ...\n\n\nclass Table:\n    _defaults = {}\n\n    def __init__(self):\n" \
           "        self._ours = 1\n"
    source = '''import os
import tomlkit.items
from tomlkit.container import _Helper
from monoguide.drivers import ours
from monoguide.drivers.ours import Table


def write(table, doc):
    table.value._insert_after("a", "b", 1)
    ours._exit()
    self._cache = table._ours + Table._defaults + table.__dict__ + ours.Table._defaults
    os._exit(0)
    tomlkit.items._parse(doc)
    return getattr(table, "_hidden"), getattr(table, "_ours"), _private_local
'''
    hits = [(hit.path, hit.line, hit.expression) for hit in scan({"drivers/ours.py": ours, "drivers/x.py": source})]
    assert sorted(hits) == [("drivers/x.py", 3, "from tomlkit.container import _Helper"),
                            ("drivers/x.py", 9, "table.value._insert_after"), ("drivers/x.py", 12, "os._exit"),
                            ("drivers/x.py", 13, "tomlkit.items._parse"),
                            ("drivers/x.py", 14, "getattr(table, '_hidden')")]


# --- the scan ------------------------------------------------------------------------------------


@cache
def repository_hits() -> list[Hit]:
    """Every private name of a dependency used by a module of the repository."""
    return scan({path.relative_to(ROOT).as_posix(): path.read_text(encoding="utf-8") for path in _modules()})


def scan(sources: dict[str, str]) -> list[Hit]:
    """The hits in the modules ``sources`` (path -> text), monoguide's names being those they define."""
    trees = {path: ast.parse(text, path) for path, text in sources.items()}
    modules = {"monoguide"} | {part.removesuffix(".py") for path in trees for part in Path(path).parts}
    ours = modules.union(*(_defined_names(tree) for tree in trees.values()))
    return [hit for path, tree in trees.items() for hit in private_uses(tree, path, ours, modules)]


def private_uses(tree: ast.Module, path: str, ours: set[str], our_modules: set[str]) -> list[Hit]:
    """The hits in one module (see the module's docstring); ``ours``: the names monoguide defines, ``our_modules``:
    the top-level names of its importable modules and packages."""
    foreign = _imported_from_dependencies(tree, our_modules)
    hits: list[Hit] = []
    for node in ast.walk(tree):
        access = _private_access(node)
        if access is not None and _uses_private(*access, ours, foreign):
            hits.append(Hit(path, node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and _root(node.module or "") not in our_modules:
            if _private_module(node.module or ""):
                hits.append(Hit(path, node.lineno, f"from {node.module} import ..."))
            hits.extend(Hit(path, node.lineno, f"from {node.module} import {alias.name}")
                        for alias in node.names if _is_private(alias.name))
        elif isinstance(node, ast.Import):
            hits.extend(Hit(path, node.lineno, f"import {alias.name}") for alias in node.names
                        if _root(alias.name) not in our_modules and _private_module(alias.name))
    return hits


def _private_access(node: ast.AST) -> tuple[ast.expr, str] | None:
    """``(x, "_name")`` of ``x._name`` or ``getattr(x, "_name", ...)`` (setattr, hasattr, delattr), else None."""
    if isinstance(node, ast.Attribute) and _is_private(node.attr):
        return node.value, node.attr
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and len(node.args) >= 2
            and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
            and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
            and _is_private(node.args[1].value)):
        return node.args[0], node.args[1].value
    return None


def _uses_private(receiver: ast.expr, name: str, ours: set[str], foreign: set[str]) -> bool:
    """Whether ``receiver.name`` (``name`` private) is a dependency's: the receiver comes from a dependency's
    import, or it is no name of ours on anything but ``self``/``cls``."""
    root = receiver
    while isinstance(root, ast.Attribute):
        root = root.value
    if isinstance(root, ast.Name) and root.id in foreign:
        return True
    if isinstance(receiver, ast.Name) and receiver.id in ("self", "cls"):
        return False
    return name not in ours


def _imported_from_dependencies(tree: ast.Module, our_modules: set[str]) -> set[str]:
    """The names a module binds by importing from a dependency (``import os``, ``from tomlkit import items``)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names
                         if _root(alias.name) not in our_modules)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and _root(node.module or "") not in our_modules:
            names.update(alias.asname or alias.name for alias in node.names)
    return names


def _defined_names(tree: ast.Module) -> set[str]:
    """What a module of ours defines: functions, methods and classes at any depth, the names bound at module level
    and in class bodies, and the attributes it sets on ``self`` or ``cls``."""
    names = set(_bound_at_level(tree.body))
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        if isinstance(node, ast.ClassDef):
            names.update(_bound_at_level(node.body))
        elif (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and isinstance(node.value, ast.Name)
              and node.value.id in ("self", "cls")):
            names.add(node.attr)
    return names


def _bound_at_level(body: Iterable[ast.stmt]) -> Iterator[str]:
    """The names the statements of a module or class body bind (in their if/try/with/for blocks too, not inside
    the functions, classes, lambdas and comprehensions they hold: those have their own scope)."""
    for statement in body:
        yield from _bound_in(statement)


def _bound_in(node: ast.AST) -> Iterator[str]:
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef | ast.Lambda | ast.ListComp
                  | ast.SetComp | ast.DictComp | ast.GeneratorExp):
        return
    if isinstance(node, ast.Import | ast.ImportFrom):
        yield from ((alias.asname or alias.name).split(".")[0] for alias in node.names)
    elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
        yield node.id
    for child in ast.iter_child_nodes(node):
        yield from _bound_in(child)


def _modules() -> list[Path]:
    return sorted(path for path in ROOT.rglob("*.py")
                  if not any(part.startswith(".") or part in NOT_OURS or part.endswith(".egg-info")
                             for part in path.relative_to(ROOT).parts[:-1]))


def _is_private(name: str) -> bool:
    return name.startswith("_") and name != "_" and not (name.startswith("__") and name.endswith("__"))


def _private_module(dotted: str) -> bool:
    return any(_is_private(part) for part in dotted.split("."))


def _root(dotted: str) -> str:
    return dotted.split(".")[0]
