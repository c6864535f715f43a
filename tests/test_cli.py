"""Every registered command loads, declares flags that its run function takes, and answers --help."""

import argparse
import subprocess
import sys

import pytest

from spikejax import cli
from spikejax.commands import Command, run_parameters

POINTS = [(group, name, point) for group, names in cli.registered().items() for name, point in names.items()]


def _dests(parser: argparse.ArgumentParser) -> set[str]:
    return {a.dest for a in parser._actions if a.dest != "help"}


@pytest.mark.parametrize(("group", "name", "point"), POINTS, ids=[p.name for _, _, p in POINTS])
def test_registered_command_loads_and_its_flags_are_its_run_arguments(group, name, point):
    command = cli.load(point)
    assert isinstance(command, Command)
    parser = command.parser(f"spikejax {group} {name}")
    assert _dests(parser) == run_parameters(command)
    with pytest.raises(SystemExit) as done:
        parser.parse_args(["--help"])
    assert done.value.code == 0


def test_every_command_of_the_readme_is_registered():
    names = {p.name for _, _, p in POINTS}
    assert {"info", "sweep", "detect.pipe", "bench.hough", "reproduce.gaits", "bench.robobee"} <= names


@pytest.mark.parametrize(
    "argv", [["--help"], ["reproduce", "--help"], ["bench", "--help"], ["detect", "pipe", "--help"]]
)
def test_help_through_the_cli(argv):
    run = subprocess.run([sys.executable, "-m", "spikejax.cli", *argv], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "usage: spikejax" in run.stdout


def test_unknown_command_is_one_line():
    run = subprocess.run([sys.executable, "-m", "spikejax.cli", "reproduce", "nothing"], capture_output=True, text=True)
    assert run.returncode == 2
    assert "invalid choice: 'nothing'" in run.stderr
    assert "Traceback" not in run.stderr
