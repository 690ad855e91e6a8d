"""The ``piezopreload`` command line: a thin layer over the Python API.

Every subcommand parses its arguments, calls the API, and prints a human table or, with
``--json``, one JSON object on stdout (the result's ``to_dict()``). It exits 0 on success, 2
on bad input with one ``error: ...`` line on stderr, 1 on an internal failure; ``rig run``
and ``rig serve`` exit 3 when an interlock or a signal stopped the run. Set
``PIEZOPRELOAD_DEBUG=1`` to see the traceback of an internal failure. Each subcommand has one
``register_*`` function beside its handler and printer, in a module of this package per command
(or group of commands); :data:`COMMANDS` lists them in the order ``--help`` shows.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from piezopreload.cli._common import EXIT_INPUT, EXIT_INTERNAL, EXIT_OK, Parser, command_help, exit_code_of
from piezopreload.cli.autotune import register_autotune
from piezopreload.cli.codesign import register_codesign
from piezopreload.cli.design import register_ballscrew, register_design
from piezopreload.cli.export import register_export
from piezopreload.cli.identify import register_identify
from piezopreload.cli.learn import register_learn
from piezopreload.cli.rig import register_rig
from piezopreload.cli.study import register_report, register_reproduce, register_run, register_simulate
from piezopreload.cli.sweep import register_sweep
from piezopreload.cli.tune import register_tune, register_validate
from piezopreload.core.errors import InternalError, PiezopreloadError

__all__ = ["main", "build_parser", "COMMANDS", "EXIT_OK", "EXIT_INTERNAL", "EXIT_INPUT"]


# --------------------------------------------------------------------------------------
# the parser
# --------------------------------------------------------------------------------------
#: one register function per subcommand, in the order ``--help`` lists them: ``register_NAME`` registers NAME, the
#: first line of its docstring is NAME's line in ``--help``; it imports the floors' constants its choices name
COMMANDS: tuple[Callable[[Any], None], ...] = (
    register_run, register_sweep, register_report, register_identify, register_simulate, register_reproduce,
    register_tune, register_autotune, register_codesign, register_learn, register_validate, register_ballscrew,
    register_design, register_export, register_rig,
)


class _Version(argparse.Action):
    """``--version``: the installed package's version, read when asked (not on every start)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="show the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        from piezopreload.core.artifacts import package_version

        print(f"piezopreload {package_version()}")
        parser.exit()


class _Listed:
    """What :func:`build_parser` hands a register function: ``add_parser`` lists the subcommand with its line."""

    def __init__(self, sub: Any, register: Callable[[Any], None]) -> None:
        self.sub, self.register = sub, register

    def add_parser(self, name: str, **kwargs: Any) -> Parser:
        return self.sub.add_parser(name, help=command_help(self.register), **kwargs)


def build_parser(*, deferred: bool = False) -> argparse.ArgumentParser:
    """The command line's parser. ``deferred``: each subcommand's arguments are registered when it is used (what
    ``main`` does: ``piezopreload --help`` lists the subcommands without loading the floors their choices name)."""
    parser = Parser(prog="piezopreload",
                     description="Design and tuning studies for feed drives whose ball-screw "
                                 "preload is set by piezo stacks.")
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for register in COMMANDS:
        if deferred:
            sub.add_parser(register.__name__.removeprefix("register_"), help=command_help(register)).deferred = register
        else:
            register(_Listed(sub, register))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(deferred=True)
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return EXIT_INPUT
        result = args.run(args)
    except PiezopreloadError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return int(getattr(exc, "exit_code", EXIT_INTERNAL if isinstance(exc, InternalError) else EXIT_INPUT))
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal failure: one line, the traceback on request
        if os.environ.get("PIEZOPRELOAD_DEBUG"):
            traceback.print_exc()
        print(f"error: internal failure: {type(exc).__name__}: {exc} "
              "(set PIEZOPRELOAD_DEBUG=1 for the traceback)", file=sys.stderr)
        return EXIT_INTERNAL
    if args.json:
        print(json.dumps(result if isinstance(result, dict) else result.to_dict(), allow_nan=False))
    else:
        args.show(result)
    return exit_code_of(result)

