"""What a ``spikejax`` command is: its help, the flags it declares, and the function it runs.

A command is registered as an entry point of the group ``spikejax.commands``,
named ``GROUP.NAME`` for ``spikejax GROUP NAME`` (``reproduce.gaits``,
``bench.hough``, ``detect.pipe``) or ``NAME`` for ``spikejax NAME``
(``sweep``, ``info``), and pointing at a `Command`::

    [project.entry-points."spikejax.commands"]
    "reproduce.gaits" = "robots.hexapod.reproduce:command"

A package of one's own (a robot of one's own) registers its commands the same
way; ``spikejax`` finds them when the package is installed. The CLI imports a
group's commands only when that group is asked for, so a command module may
import JAX at its top.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from collections.abc import Callable

__all__ = ["Command", "OneLineParser", "add_common", "count", "positive_float", "run_parameters"]


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (``PROG: error: ...``, exit status 2), without the usage."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


@dataclasses.dataclass(frozen=True)
class Command:
    """One ``spikejax`` command.

    Attributes:
        help: one line, shown in the list of commands.
        add_arguments: declares every flag of the command on an
            ``argparse.ArgumentParser``.
        run: runs the command. It takes every flag as a keyword argument named
            after the flag's ``dest`` (``--cpu-devices`` is ``cpu_devices``) and
            returns the exit status (``None`` is 0). It raises
            ``spikejax.errors.UserError`` for a bad input, which the CLI prints
            as one line with exit status 2.
        description: the longer text of ``--help`` (default: ``help``).
    """

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[..., int | None]
    description: str | None = None

    def parser(self, prog: str) -> argparse.ArgumentParser:
        """A parser for this command alone (what ``--help`` shows)."""
        parser = OneLineParser(prog=prog, description=self.description or self.help)
        self.add_arguments(parser)
        return parser


def run_parameters(command: Command) -> set[str]:
    """The keyword arguments ``command.run`` takes (the flags' ``dest`` names must be these)."""
    return {
        name
        for name, p in inspect.signature(command.run).parameters.items()
        if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)
    }


def count(text: str) -> int:
    """``argparse`` type of a count that must be at least 1 (``--trials``, ``--cpu-devices``)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def positive_float(text: str) -> float:
    """``argparse`` type of a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def add_common(
    parser: argparse.ArgumentParser,
    *,
    out_required: bool = True,
    trials: str | None = None,
    chunk_size: bool = False,
    progress: bool = True,
) -> None:
    """Declare the flags most commands share: ``--out``, ``--trials``, ``--chunk-size``, ``--no-progress``.

    Args:
        parser: the command's parser.
        out_required: whether ``--out DIR`` must be given (else it defaults to None).
        trials: the help text of ``--trials N`` (None: no such flag).
        chunk_size: whether to declare ``--chunk-size N`` (trials per compiled batch).
        progress: whether to declare ``--no-progress``.
    """
    parser.add_argument("--out", required=out_required, default=None, help="output directory")
    if trials is not None:
        parser.add_argument("--trials", type=count, default=None, help=trials)
    if chunk_size:
        parser.add_argument("--chunk-size", type=count, default=None, help="trials per compiled batch")
    if progress:
        parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
