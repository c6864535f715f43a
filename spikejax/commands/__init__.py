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
import contextlib
import dataclasses
import functools
import inspect
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from spikejax.errors import UserError

__all__ = [
    "MARKER",
    "Command",
    "OneLineParser",
    "add_common",
    "add_cpu_devices",
    "count",
    "count_or_zero",
    "output_directory",
    "positive_float",
    "run_parameters",
    "writes_output",
]

MARKER = ".spikejax-output"
"""The file that marks a command's output directory: one line per command that wrote there."""


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


def _whole_number(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
    return value


def count(text: str) -> int:
    """``argparse`` type of a count that must be at least 1 (``--trials``, ``--cpu-devices``)."""
    return _whole_number(text, 1)


def count_or_zero(text: str) -> int:
    """``argparse`` type of a count that may be 0 (an optional extra study: ``--empty 0`` skips it)."""
    return _whole_number(text, 0)


def positive_float(text: str) -> float:
    """``argparse`` type of a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def add_cpu_devices(parser: argparse.ArgumentParser, *, peers: str) -> None:
    """Declare a benchmark's ``--cpu-devices N``: the CPU devices JAX presents, and the cores the peers get.

    Args:
        parser: the command's parser.
        peers: what else takes that many cores, for the help (``"the peers' processes"``).
    """
    parser.add_argument(
        "--cpu-devices",
        type=count,
        default=None,
        help=f"CPU devices JAX presents (default: one per core); also {peers}",
    )


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


def _refuse(flag: str, path: Path, why: str) -> UserError:
    return UserError(f"{flag} {path}: {why}")


def _check_output(path: Path, command: str, flag: str, shared_with: Iterable[str]) -> None:
    """Refuse an output directory that cannot be used, without touching anything."""
    if path.exists() and not path.is_dir():
        raise _refuse(flag, path, "is a file, not a directory")
    if not path.exists():
        above = path.parent
        while not above.exists() and above != above.parent:
            above = above.parent
        if not above.is_dir():
            raise _refuse(flag, path, f"{above} is a file, not a directory")
        if not os.access(above, os.W_OK | os.X_OK):
            raise _refuse(flag, path, f"cannot create it, {above} is not writable")
        return
    if not os.access(path, os.W_OK | os.X_OK):
        raise _refuse(flag, path, "the directory is not writable")
    if not any(path.iterdir()):
        return
    marker = path / MARKER
    if not marker.is_file():
        raise _refuse(
            flag,
            path,
            f"the directory is not empty and is not an earlier output of spikejax {command} "
            f"(no {MARKER} in it); give a new or an empty directory",
        )
    try:
        wrote = [line.strip() for line in marker.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as err:
        raise _refuse(flag, path, f"cannot read {MARKER} ({err.__class__.__name__})") from None
    if not {command, *shared_with} & set(wrote):
        raise _refuse(
            flag,
            path,
            f"the directory holds the output of spikejax {', '.join(wrote) or 'another command'}, "
            f"not of spikejax {command}; give a new or an empty directory",
        )


def writes_output(command: str, *, shared_with: Iterable[str] = ()) -> Callable:
    """Decorator of a command's run function whose ``out`` flag is optional: `output_directory` around it.

    When ``out`` is given, it is checked before the run does any work and
    handed to it as a `pathlib.Path`; the run's signature is kept (so its flags
    still match, `run_parameters`).
    """

    def wrap(run: Callable[..., int | None]) -> Callable[..., int | None]:
        @functools.wraps(run)
        def checked(**flags: Any) -> int | None:
            if flags.get("out") is None:
                return run(**flags)
            with output_directory(flags["out"], command=command, shared_with=shared_with) as out:
                return run(**{**flags, "out": out})

        return checked

    return wrap


@contextlib.contextmanager
def output_directory(
    path: str | os.PathLike, *, command: str, flag: str = "--out", shared_with: Iterable[str] = ()
) -> Iterator[Path]:
    """The output directory of a command, checked before any work; ``with output_directory(out, command=...)``.

    A path that cannot be used is refused at once with a one-line `UserError`
    naming ``flag``: a file, a path below a file, a directory that is not
    writable, or a non-empty directory that is not an earlier output of
    ``command`` (or of one of ``shared_with``): the file `MARKER`, written into
    the directory on first use, names the commands that wrote there. An earlier
    output is used again (a command resumes or overwrites its own files).

    The directory (and its parents) is created on entry; if the block raises
    and leaves nothing in a directory created here but the marker, the
    directory is removed again, so a refused input leaves no empty output
    directory behind.

    Args:
        path: the directory the user gave.
        command: the command, as typed after ``spikejax`` (``"detect pipe"``).
        flag: the flag the path came from, for the messages.
        shared_with: other commands whose output may share the directory
            (``make demo`` writes ``reproduce gaits`` and ``reproduce gait-choices`` into one).

    Yields:
        The directory, a `pathlib.Path`.
    """
    path = Path(path)
    _check_output(path, command, flag, shared_with)
    created = None
    if not path.exists():
        created = path
        while not created.parent.exists():
            created = created.parent
    marker = path / MARKER
    fresh = created is not None or not marker.exists()  # nothing of an earlier run is there
    try:
        path.mkdir(parents=True, exist_ok=True)
        wrote = marker.read_text().split("\n") if marker.is_file() else []
        if command not in (line.strip() for line in wrote):
            with open(marker, "a") as f:
                f.write(f"{command}\n")
    except OSError as err:
        _remove_unused(path, created, fresh)
        raise _refuse(flag, path, f"cannot write to it ({err.strerror or err.__class__.__name__})") from None
    try:
        yield path
    except BaseException:
        _remove_unused(path, created, fresh)
        raise


def _remove_unused(path: Path, created: Path | None, fresh: bool) -> None:
    """Undo `output_directory` where nothing but markers was written: the directories it created, or its marker
    in a directory that was empty (best effort)."""
    with contextlib.suppress(OSError):
        if created is not None and created.is_dir() and _only_marker_tree(created):
            for root, _, files in os.walk(created, topdown=False):
                for name in files:
                    os.remove(os.path.join(root, name))
                os.rmdir(root)
        elif fresh and path.is_dir() and [entry.name for entry in path.iterdir()] == [MARKER]:
            (path / MARKER).unlink()


def _only_marker_tree(path: Path) -> bool:
    """Whether ``path`` holds nothing but empty directories and marker files."""
    for root, _, files in os.walk(path):
        if any(name != MARKER for name in files):
            return False
    return True
