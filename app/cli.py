"""The `skelasm` command: precompute, evaluate, landscape, search, simulate, bench, report, gui."""

from __future__ import annotations

import argparse
import importlib
import os
import re
import signal
import sys
import threading

#: Subcommand name -> module in app.commands providing add_parser(subparsers) and run(args).
COMMANDS = ("scene", "precompute", "evaluate", "landscape", "search", "simulate", "bench", "report",
            "gui", "warm")


class UserError(Exception):
    """A problem the user can fix (bad file, bad option): printed as one message, exit 2."""


#: A negative number in any notation Python's float() reads (-4.2e-18, -.5, -1_000, -inf):
#: argparse's own pattern knows only -12 and -1.5, and takes -4.2e-18 for an option.
NEGATIVE_NUMBER = re.compile(
    r"^-(\d[\d_]*\.?[\d_]*|\.\d[\d_]*)([eE][-+]?\d[\d_]*)?$|^-(inf|infinity|nan)$",
    re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """An ArgumentParser (and its subcommands' parsers) that reads any negative float.

    A bad option is one line, like every other error (argparse's usage block drowned it),
    and a JSON object on stdout when ``--json`` was asked for.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str):  # type: ignore[override]  # argparse's is NoReturn
        """Print ``message`` as one line (and as JSON with ``--json``), exit with status 2."""
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        if "--json" in sys.argv[1:] or _JSON_REQUESTED:
            _print_json_error(message, None, None)
        sys.exit(2)


#: Set by main() when its argument list asks for --json (the parser sees no sys.argv then).
_JSON_REQUESTED = False


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (a closed terminal): unwinds like Ctrl+C so every output is kept."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated(signum)


def _catch_termination() -> dict[int, object]:
    """Turn SIGTERM and SIGHUP into :class:`Terminated` (main thread only).

    By default they end the process at once: a log half-written, its temporary file left.
    Raised as an exception, they run the same ``finally`` and ``except`` blocks Ctrl+C runs.
    Returns the handlers replaced, to put back when the command ends.
    """
    replaced: dict[int, object] = {}
    if threading.current_thread() is not threading.main_thread():
        return replaced
    for name in ("SIGTERM", "SIGHUP"):
        number = getattr(signal, name, None)
        if number is not None and signal.getsignal(number) in (signal.SIG_DFL, None):
            replaced[number] = signal.signal(number, _raise_terminated)
    return replaced


def _error_location(exc: BaseException) -> tuple[str | None, int | None]:
    """The file and line an error names: its ``path`` and ``line``, else its message's start."""
    file = getattr(exc, "path", None) or None
    line = getattr(exc, "line", None)
    if file is None:
        m = re.match(r"^(.+?)(?::(\d+))?: ", str(exc))
        if m and not m.group(1).startswith("-") and (" " not in m.group(1)
                                                      or os.path.exists(m.group(1))):
            file = m.group(1)
            line = int(m.group(2)) if m.group(2) else None
    return (str(file) if file else None), (int(line) if line is not None else None)


def _in_scene(args: argparse.Namespace, exc: BaseException) -> BaseException | None:
    """The error at its scene file's line when it is about a key the scene sets, else None.

    Some ranges are checked once the parts are loaded (inertia against the mesh's, kappa
    against its default, a pose against the part's size): the message then names the key
    but not where it is written.
    """
    from engine.errors import InputError

    if not isinstance(exc, InputError) or getattr(exc, "path", None):
        return None
    scene = getattr(args, "scene", None) or getattr(args, "part", None)
    if not scene or not str(scene).lower().endswith(".toml"):
        return None
    if getattr(args, "start", None) is not None and str(exc).startswith("proxy pose"):
        return None  # the pose came from --start
    from engine.scene.reader import locate_late_error

    return locate_late_error(scene, str(exc))


def _print_json_error(message: str, file: str | None, line: int | None) -> None:
    import json

    print(json.dumps({"error": message, "file": file, "line": line}), flush=True)


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


def _leave(status: int, argv: list[str] | None) -> int:
    """``status``, or the process ended with it at once if a signal left a call running.

    When a signal made the command abandon a compiled call (:func:`engine.interrupt.in_flight`)
    the command's own clean-up has run, and finalising the runtime under that call aborted
    the exit (PoCL, SIGABRT). Only for the console script (``argv`` None); a caller in
    Python gets the status back.
    """
    from engine.interrupt import in_flight

    if argv is None and in_flight():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `skelasm` console script."""
    from engine.backend import check_environment
    from engine.cache import max_bytes
    from engine.errors import ResourceError

    global _JSON_REQUESTED
    _JSON_REQUESTED = argv is not None and "--json" in argv
    parser = build_parser()
    args = parser.parse_args(argv)
    as_json = bool(getattr(args, "json", False))

    def fail(exc: BaseException, message: str, status: int) -> int:
        print(f"skelasm {args.command}: error: {message}", file=sys.stderr)
        if as_json:
            _print_json_error(message, *_error_location(exc))
        return status

    replaced: dict[int, object] = {}
    try:
        if args.command != "gui":  # the window handles its own ending
            replaced = _catch_termination()
            if argv is None:  # the console script: a signal acts inside compiled calls too
                from engine.interrupt import enable

                enable()
            # trimesh swallows a signal that lands in its imports: import it first, held
            from engine.loading import import_trimesh

            import_trimesh()
        check_environment()
        max_bytes()  # a bad SKELASM_CACHE_MAX_GB is refused now, not after the computation
        return int(args.run(args) or 0)
    except Terminated as exc:
        name = signal.Signals(exc.signum).name
        print(f"skelasm: stopped by {name}", file=sys.stderr)
        if as_json:
            _print_json_error(f"stopped by {name}", None, None)
        return _leave(128 + exc.signum, argv)
    except KeyboardInterrupt:
        print("skelasm: interrupted", file=sys.stderr)
        if as_json:
            _print_json_error("interrupted", None, None)
        return _leave(130, argv)
    except (UserError, ValueError, OSError, ResourceError) as exc:
        # Every engine error meant for the user is a ValueError/OSError subclass with a message
        # that names the problem and the fix; a traceback would only hide it. A refusal for
        # memory (ResourceError) answers a bad input too (a grid too fine): exit 2 as well.
        located = _in_scene(args, exc)
        return fail(located or exc, str(located or exc), 2)
    except MemoryError as exc:
        # an allocation no estimate foresaw: still one line and the fix
        return fail(exc, f"out of memory ({exc or 'allocation failed'}); use a coarser grid "
                    "(smaller --grid or larger --spacing) or a shorter run", 2)
    except RecursionError as exc:
        return fail(exc, f"an input nested too deeply to read ({exc}); check the file", 2)
    except RuntimeError as exc:
        return fail(exc, str(exc), 1)
    finally:
        for number, handler in replaced.items():
            signal.signal(number, handler)  # type: ignore[arg-type]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
