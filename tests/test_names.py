"""One spelling for public names: British, as the project's prose (centre, colour).

The libraries' own spellings (Qt's ``color()``, pyvista's and matplotlib's ``color=``)
stay theirs. No second spelling is kept as an alias: a property or function named
``center`` fails the check whatever its docstring says.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Names spelled the American way on purpose: the scene file's key and the field that
#: mirrors it (changing a file format's key breaks users' files).
AMERICAN_ON_PURPOSE = {"center_of_mass"}


def _public_names(tree: ast.AST):
    """(name, line) of what a module defines for others: functions, their arguments,
    classes, class attributes and module-level names.
    """
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node.name, node.lineno
            for a in node.args.args + node.args.kwonlyargs:
                yield a.arg, a.lineno
        elif isinstance(node, ast.ClassDef):
            yield node.name, node.lineno
            for item in node.body:
                if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    yield item.target.id, item.lineno
    for node in getattr(tree, "body", []):
        if isinstance(node, ast.Assign):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    yield target.id, node.lineno


@pytest.mark.parametrize("folder", ["engine", "app", "bench"])
def test_public_names_have_one_spelling(folder: str) -> None:
    """British, as the prose: centre and colour (the libraries' own color= stays theirs)."""
    found = []
    for source in sorted((ROOT / folder).rglob("*.py")):
        tree = ast.parse(source.read_text(encoding="utf-8"))
        for name, line in _public_names(tree):
            if name in AMERICAN_ON_PURPOSE:
                continue
            if re.search(r"center|color", name, re.IGNORECASE):
                found.append(f"{source.relative_to(ROOT)}:{line} {name}")
    assert not found, found
