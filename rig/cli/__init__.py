"""The `rig` command: one subcommand per module in this package, dispatched by argparse.

Exit codes (`rig.errors.ExitCode`, docs/design.md §5): 0 done; 1 stopped by a fault or abort, hardware
left safe; 2 invalid input, nothing started; 130 interrupted, hardware left safe. User errors are one
line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from rig import __version__
from rig.cli.commands import COMMANDS, module_name
from rig.errors import ExitCode, InputError, RigError, one_line
from rig.safety.interrupts import interrupts_deferred, interrupts_held, terminate_as_interrupt

# What other code may use: the entry point; its command modules are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES: tuple[str, ...] = ()
__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    """argparse with the rig's one-line error format (argparse already exits 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(ExitCode.INVALID_INPUT, f"{self.prog}: error: {message}\n")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The `rig` parser: every command's in full, or, given the `argv` to parse, only the one it names.

    Given `argv`, the other commands are listed with their summaries (`rig.cli.commands`) but
    their modules, and what those import, are not loaded: a start-up pays for one command.
    """
    parser = _Parser(
        prog="rig",
        description=(
            "Automated slip trials on a deformable link of preloaded spherical joints: "
            "run protocols on a real or simulated rig, fit mu_s*delta0 and joint capacities, "
            "predict payloads, and replay MCAP logs."
        ),
        epilog="Run `rig COMMAND --help` for the options of one command.",
    )
    parser.add_argument("--version", action="version", version=f"rig {__version__}")
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND", parser_class=_Parser)
    # The top level has no option that takes a value: the first word that is not an option is the command.
    named = None if argv is None else next((word for word in argv if not word.startswith("-")), None)
    for name, summary in COMMANDS.items():
        if argv is None or name == named:
            importlib.import_module(module_name(name)).register(subparsers)
        else:
            subparsers.add_parser(name, help=summary)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `rig` console script; returns the process exit code.

    From its first instruction a SIGTERM is a Ctrl-C, and a Ctrl-C anywhere (importing the commands,
    parsing, running) exits 130 without a traceback.
    """
    terminate_as_interrupt()
    try:
        # Importing the commands takes most of a start-up. A Ctrl-C that lands inside importlib's
        # module-lock cleanup (a weakref callback) is printed and swallowed there, and the command
        # then ran on as if nothing came: so it waits until the imports are done.
        words = sys.argv[1:] if argv is None else list(argv)
        with interrupts_deferred():
            parser = build_parser(words)
        args = parser.parse_args(words)
        handler = getattr(args, "handler", None)
        if handler is None:
            parser.print_help(sys.stderr)
            return ExitCode.INVALID_INPUT
        return int(handler(args))
    except InputError as exc:
        print(f"rig: error: {one_line(str(exc))}", file=sys.stderr)
        return ExitCode.INVALID_INPUT
    except KeyboardInterrupt:
        with interrupts_held():  # a second one must not turn this into a traceback
            print("rig: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED
    except RigError as exc:
        print(f"rig: {type(exc).__name__}: {one_line(str(exc))}", file=sys.stderr)
        return ExitCode.FAULT
    except BrokenPipeError:
        # The reader of stdout went away (`rig fit ... | head`): no traceback, and nothing more to
        # write there (Python flushes stdout again at exit, which would raise once more).
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return ExitCode.FAULT


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
