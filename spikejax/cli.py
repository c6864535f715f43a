"""The ``spikejax`` command: finds the commands registered as entry points and runs one.

Commands register under the entry-point group ``spikejax.commands`` (see
``spikejax.commands``): ``reproduce.gaits`` is ``spikejax reproduce gaits``,
``sweep`` is ``spikejax sweep``. ``spikejax`` names no command itself, so the
library imports no robot: the robots (or any installed package) register theirs.
Only the commands of the group asked for are imported.
"""

from __future__ import annotations

import argparse
import sys
from importlib.metadata import EntryPoint, entry_points

from spikejax.commands import Command, OneLineParser
from spikejax.errors import UserError

GROUP = "spikejax.commands"


def registered() -> dict[str, dict[str, EntryPoint]]:
    """The registered commands, ``{group: {name: entry point}}``; a single command is ``{name: {"": ...}}``."""
    found: dict[str, dict[str, EntryPoint]] = {}
    for point in entry_points(group=GROUP):
        group, _, name = point.name.partition(".")
        found.setdefault(group, {})[name] = point
    return dict(sorted(found.items()))


def load(point: EntryPoint) -> Command:
    """The `Command` an entry point names; a UserError if it names something else."""
    command = point.load()
    if not isinstance(command, Command):
        raise UserError(f"entry point {point.name} = {point.value} is not a spikejax.commands.Command")
    return command


def _top_parser(commands: dict[str, dict[str, EntryPoint]]) -> argparse.ArgumentParser:
    parser = OneLineParser(prog="spikejax", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=list(commands), metavar="COMMAND", help=", ".join(commands))
    parser.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    return parser


def _command_parser(group: str, points: dict[str, EntryPoint], asked: str | None) -> argparse.ArgumentParser:
    """The parser of ``spikejax GROUP``: the command itself, or a sub-parser per command of the group.

    Only the command ``asked`` for is imported; all of the group's are when none of them is
    named (for the group's ``--help``, or to refuse a name that is not there).
    """
    if list(points) == [""]:
        command = load(points[""])
        parser = command.parser(f"spikejax {group}")
        parser.set_defaults(_command=command)
        return parser
    parser = OneLineParser(prog=f"spikejax {group}")
    sub = parser.add_subparsers(dest="_name", required=True, metavar="TARGET")
    for name, point in sorted(points.items()):
        if asked in points and name != asked:
            sub.add_parser(name)
            continue
        command = load(point)
        one = sub.add_parser(name, help=command.help, description=command.description or command.help)
        command.add_arguments(one)
        one.set_defaults(_command=command)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``spikejax ARGS``; returns the exit status (2 with one line on stderr for a bad input)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    commands = registered()
    top = _top_parser(commands)
    if not argv or argv[0] in ("-h", "--help"):
        top.print_help()
        return 0 if argv else 2
    head = top.parse_args(argv[:1])
    name = head.command
    try:
        asked = argv[1] if len(argv) > 1 else None
        args = vars(_command_parser(name, commands[name], asked).parse_args(argv[1:]))
        command: Command = args.pop("_command")
        name = " ".join([name, args.pop("_name", "")]).strip()
        return int(command.run(**args) or 0)
    except UserError as err:
        print(f"spikejax {name}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"spikejax {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
