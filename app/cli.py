"""The `skelasm` command: precompute, evaluate, landscape, simulate, bench, report, gui."""

from __future__ import annotations

import argparse
import importlib
import re
import sys

#: Subcommand name -> module in app.commands providing add_parser(subparsers) and run(args).
COMMANDS = ("scene", "precompute", "evaluate", "landscape", "simulate", "bench", "report", "gui")


class UserError(Exception):
    """A problem the user can fix (bad file, bad option): printed as one message, exit 2."""


#: A negative number in any notation Python's float() reads (-4.2e-18, -.5, -1_000, -inf):
#: argparse's own pattern knows only -12 and -1.5, and takes -4.2e-18 for an option.
NEGATIVE_NUMBER = re.compile(
    r"^-(\d[\d_]*\.?[\d_]*|\.\d[\d_]*)([eE][-+]?\d[\d_]*)?$|^-(inf|infinity|nan)$",
    re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """An ArgumentParser (and its subcommands' parsers) that reads any negative float."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""
    parser = Parser(
        prog="skelasm",
        description="Force-guided assembly of CAD parts with skeletal densities and "
        "Fourier correlations.",
    )
    parser.add_argument("--version", action="version", version="skelasm 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"app.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"app.commands.{name}":
                raise
            sub.add_parser(name, help="(not available in this installation)").set_defaults(
                run=_unavailable(name)
            )
            continue
        module.add_parser(sub)
    return parser


def _unavailable(name: str):
    def run(args: argparse.Namespace) -> int:
        raise UserError(f"the `{name}` command is not available in this installation")

    return run


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `skelasm` console script."""
    from engine.backend import check_environment
    from engine.errors import ResourceError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        check_environment()
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        print("skelasm: interrupted", file=sys.stderr)
        return 130
    except (UserError, ValueError, OSError, ResourceError) as exc:
        # Every engine error meant for the user is a ValueError/OSError subclass with a message
        # that names the problem and the fix; a traceback would only hide it. A refusal for
        # memory (ResourceError) answers a bad input too (a grid too fine): exit 2 as well.
        print(f"skelasm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError as exc:
        # an allocation no estimate foresaw: still one line and the fix
        print(f"skelasm {args.command}: error: out of memory ({exc or 'allocation failed'}); "
              "use a coarser grid (smaller --grid or larger --spacing) or a shorter run",
              file=sys.stderr)
        return 2
    except RuntimeError as exc:
        print(f"skelasm {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
