"""Every default is written once: messages and help texts read it, never copy it.

A default copied into a string (``"(default 0.5)"``) goes stale the day the engine's
value changes; ``engine.params`` (and, for the application's own options, the module that
defines the option) is the one place it is written.
"""

from __future__ import annotations

import argparse
import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: A number given as a default inside a string literal.
COPIED = re.compile(r"\bdefault:?\s+-?\d")


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the string nodes that are docstrings (they may explain a default)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def copied_defaults(source: Path, root: Path = ROOT) -> list[str]:
    """``file:line text`` for each string literal (f-strings' literal parts included) that
    writes a default as a number.
    """
    tree = ast.parse(source.read_text(encoding="utf-8"))
    skip = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                and id(node) not in skip and COPIED.search(node.value)):
            found.append(f"{source.relative_to(root)}:{node.lineno} {node.value.strip()!r}")
    return found


@pytest.mark.parametrize("folder", ["engine", "app"])
def test_no_message_or_help_copies_a_default(folder: str) -> None:
    found = [hit for source in sorted((ROOT / folder).rglob("*.py"))
             for hit in copied_defaults(source)]
    assert not found, found


def test_the_check_finds_a_copied_default(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text('"""A docstring may say (default 0.5)."""\n'
                   'HELP = "Gaussian width (default 0.5)"\n'
                   'fine = f"Gaussian width (default {WIDTH:g})"\n', encoding="utf-8")
    assert copied_defaults(bad, tmp_path) == ["bad.py:2 'Gaussian width (default 0.5)'"]


def _help(parser: argparse.ArgumentParser, *path: str) -> dict[str, str]:
    for name in path:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    return {a.dest: a.help or "" for a in parser._actions}


def test_precompute_shows_the_engines_descriptor_defaults(monkeypatch) -> None:
    """The help reads the defaults when it is built: change them, and it follows."""
    import app.commands.precompute as precompute
    from app.cli import build_parser
    from engine.params import DescriptorParams

    for name, value in (("sigma", 0.625), ("penalty", 4.5), ("lambda_out", 1.25),
                        ("padding", 7.0)):
        monkeypatch.setattr(DescriptorParams, name, value)
    monkeypatch.setattr(precompute, "DEFAULT_GRID", 72)
    helps = _help(build_parser(), "precompute")
    assert "(default 0.625)" in helps["sigma"]
    assert "(default 4.5)" in helps["penalty"]
    assert "(default 1.25)" in helps["lambda_out"]
    assert "(default 7)" in helps["padding"]
    assert "(default 72;" in helps["grid"]


def test_backend_helps_say_what_auto_means_from_the_registry() -> None:
    from app.cli import build_parser
    from engine.backend import describe_auto

    parser = build_parser()
    assert describe_auto("per_pose") in _help(parser, "evaluate")["backend"]
    assert describe_auto("descriptor") in _help(parser, "precompute")["backend"]
    assert describe_auto("per_pose") in _help(parser, "bench", "loop")["backend"]
