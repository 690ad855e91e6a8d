"""What the subcommands share: the parser that reports bad arguments in one line, argument types, the
study a single-step command works on, the Monte Carlo options and progress on standard error."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, NoReturn, Protocol, TypeVar

from piezopreload.core.errors import InputError, InternalError

if TYPE_CHECKING:  # the parser is built without the floors; a command loads what it runs
    from piezopreload.artifacts.validation import ValidationResult
    from piezopreload.tuning.identification import Window

EXIT_OK, EXIT_INTERNAL, EXIT_INPUT = 0, 1, 2


class CommandResult(Protocol):
    """What a subcommand's handler returns: a result object; its printer reads it, ``--json`` prints its
    ``to_dict()``, and its ``exit_code`` (where it has one) is the command's."""

    def to_dict(self) -> dict[str, Any]: ...


R = TypeVar("R", bound=CommandResult)


@dataclass(frozen=True)
class Written(Generic[R]):
    """A step's result and where the command wrote it (``out``, None: nowhere): ``--json`` prints the result's
    ``to_dict()`` with ``out`` beside it."""

    result: R
    out: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {**self.result.to_dict(), "out": self.out}


def exit_code_of(result: CommandResult | dict[str, Any]) -> int:
    """A command's exit code: its result's ``exit_code`` (0 where it has none)."""
    if isinstance(result, dict):
        return int(result.get("exit_code", EXIT_OK))
    return int(getattr(result, "exit_code", EXIT_OK))
PASSWORD_ENV = "PIEZOPRELOAD_RIG_PASSWORD"


class Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments as one ``error: ...`` line with exit code 2.

    A subcommand's parser may be ``deferred``: the function that registers it (``register_run``) runs, and imports
    the constants its choices name, only when the subcommand is parsed or its help shown, so the command line
    lists its subcommands without loading the floors.
    """

    deferred: Callable[[Any], None] | None = None

    def error(self, message: str) -> NoReturn:
        raise InputError(f"{self.prog}: {message} (see --help)")

    def _register(self) -> None:
        register, self.deferred = self.deferred, None
        if register is not None:
            register(_Into(self))

    def parse_known_args(self, *args: Any, **kwargs: Any) -> Any:  # argparse's, after the deferred registration
        self._register()
        return super().parse_known_args(*args, **kwargs)

    def format_help(self) -> str:
        self._register()
        return super().format_help()


class _Into:
    """What a deferred subcommand's register function adds to: the parser already listed under its name."""

    def __init__(self, parser: Parser) -> None:
        self.parser = parser

    def add_parser(self, name: str, **kwargs: Any) -> Parser:
        if self.parser.prog.split()[-1] != name:
            raise InternalError(f"the subcommand listed as '{self.parser.prog}' registers '{name}'")
        for key, value in kwargs.items():  # description, epilog, formatter_class: what it did not know when listed
            setattr(self.parser, key, value)
        return self.parser


def command_help(register: Callable[[Any], None]) -> str:
    """A subcommand's line in ``--help``: the first line of its register function's docstring."""
    return (register.__doc__ or "").strip().splitlines()[0]


def integer(low: int, what: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be {what}, got {value}")
        return value
    return parse


positive_int, nonnegative_int = integer(1, "a positive integer"), integer(0, "an integer >= 0")


def nonnegative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def time_constants(text: str) -> list[float]:
    """``'0.01,0.1,1'`` -> positive, increasing time constants in s."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(0 < x < float("inf") for x in values) or any(b <= a for a, b in zip(values, values[1:])):
        raise argparse.ArgumentTypeError(f"'{text}' is not a list of positive, "
                                         "increasing times in s (example: 0.01,0.1,1)")
    return values


def time_window(text: str | None, option: str) -> Window | None:
    """``'4:7'`` -> ``Window(4, 7)``; bad text raises :class:`InputError` naming ``option``."""
    from piezopreload.tuning.identification import Window

    if text is None:
        return None
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        t0, t1 = float(a), float(b)
    except ValueError:
        raise InputError(f"{option}: '{text}' is not T0:T1 in seconds (example: {option} 4:7)") from None
    try:
        return Window(t0, t1)
    except ValueError:
        raise InputError(f"{option}: '{text}' must have finite T0 < T1") from None


def fmt(x: float | None, unit: str = "") -> str:
    return "never" if x is None else f"{x:.3f}{unit}"  # a time never reached (the step did not settle)


def json_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print the results as one JSON object")


def accept_flag(p: argparse.ArgumentParser, use: str) -> None:
    """``--accept KEY`` (repeatable): a gain set that is not validated is ``use``d only where each requirement it
    missed is named (its key, as the refusal and the gain set's ``requirements`` give it)."""
    p.add_argument("--accept", action="append", default=[], metavar="KEY",
                   help=f"a gain set that is not validated is {use} only if each requirement it missed is accepted "
                        "by name (repeatable; the key the refusal names, e.g. validation.overshoot_max_N@2000N)")


def study_arguments(p: argparse.ArgumentParser, seed: bool = True) -> None:
    p.add_argument("--study", metavar="STUDY.toml",
                   help="study file, or a shipped study's name (default: the machine axis, machine_axis.toml, as "
                        "for 'run'; the paper's is paper2021)")
    if seed:
        p.add_argument("--seed", type=nonnegative_int, help="noise seed (default: the study's)")


def study_of(args: argparse.Namespace, gains: Any = None) -> Any:
    """The study a single-step command works on (its plant: Study.plant, its [rig] or its design's): --study, else
    the default study every command shares (the machine axis). A gain set tuned for another study is refused
    without --study, rather than run on a plant it was not tuned for."""
    from piezopreload.study import load_study

    study = load_study(args.study)
    named = None if gains is None else gains.inputs.get("study_sha256")
    if args.study is None and named and named != study.sha256:
        raise InputError(f"--gains: the gain set was tuned for the study {gains.inputs.get('study', '(unnamed)')}, "
                         f"not the default ({study.name}); name its study with --study")
    return study




def monte_carlo_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plants", type=int, metavar="N",
                   help="Monte Carlo plants (default: the study's [validation] plants, or the gain set's; 200)")
    p.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: the CPU count)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the Monte Carlo on this Dask cluster")


def check_monte_carlo(args: argparse.Namespace) -> None:
    if args.plants is not None and args.plants < 1:
        raise InputError(f"--plants: must be >= 1, got {args.plants}")
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers: must be >= 1, got {args.workers}")
    if args.scheduler is not None and not args.scheduler.startswith("tcp://"):
        raise InputError(f"--scheduler: '{args.scheduler}' is not a Dask scheduler address tcp://HOST:PORT")


def say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def print_validation_summary(v: ValidationResult) -> None:
    for key, row in v.summary().items():
        print(f"  {key:22s} worst {fmt(row['worst'])}  p95 {fmt(row['p95'])}  median {fmt(row['p50'])}")


