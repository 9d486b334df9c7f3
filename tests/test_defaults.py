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
#: Copies known and not yet derived, each with where its one source is: remove an entry
#: once the string reads the source.
KNOWN: set[tuple[str, str]] = set()


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the string nodes that are docstrings (they may explain a default)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def _own_defaults(tree: ast.AST) -> set[int]:
    """The ids of the help strings that repeat their own option's ``default=`` beside it.

    ``add_argument("--top", default=5, help="... (default 5)")`` states the option's own
    default where it is defined (``%(default)s`` would say it once); a number that lives
    elsewhere (the engine's) is a copy.
    """
    out = set()
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr == "add_argument"):
            continue
        words = {k.arg: k.value for k in node.keywords}
        default = words.get("default")
        if not (isinstance(default, ast.Constant) and isinstance(default.value, (int, float))
                and not isinstance(default.value, bool)):
            continue
        for part in ast.walk(words.get("help", ast.Constant(""))):
            if isinstance(part, ast.Constant) and isinstance(part.value, str):
                numbers = re.findall(r"\bdefault:?\s+(-?[\d.e+]+)", part.value)
                if numbers and all(_same(n, default.value) for n in numbers):
                    out.add(id(part))
    return out


def _same(text: str, value: float) -> bool:
    try:
        return float(text.rstrip(".")) == float(value)
    except ValueError:
        return False


def copied_defaults(source: Path, root: Path = ROOT) -> list[str]:
    """``file:line text`` for each string literal (f-strings' literal parts included) that
    writes a default as a number, but for an option's help repeating its own ``default=``.
    """
    tree = ast.parse(source.read_text(encoding="utf-8"))
    skip = _docstrings(tree) | _own_defaults(tree)
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
    known = {hit for hit in found for path, text in KNOWN
             if hit.startswith(f"{path}:") and hit.endswith(f"{text}'")}
    assert not set(found) - known, sorted(set(found) - known)


def test_the_check_finds_a_copied_default(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text('"""A docstring may say (default 0.5)."""\n'
                   'HELP = "Gaussian width (default 0.5)"\n'
                   'fine = f"Gaussian width (default {WIDTH:g})"\n'
                   'p.add_argument("--top", default=5, help="fits (default 5)")\n'
                   'p.add_argument("--n", default=None, help="samples (default 64)")\n'
                   'p.add_argument("--k", default=8, help="modes (default 16)")\n',
                   encoding="utf-8")
    assert copied_defaults(bad, tmp_path) == ["bad.py:2 'Gaussian width (default 0.5)'",
                                              "bad.py:5 'samples (default 64)'",
                                              "bad.py:6 'modes (default 16)'"]


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
