"""The house's layers, checked from the code's imports (every ``import``, at the top or inside a function).

    commands, benchmarks   spikejax/cli.py, spikejax/commands/, spikejax/benchmarking.py,
                           robots/*/reproduce*.py, robots/*/bench*.py, benchmarks/
    robots                 robots/ (robots, tasks, controllers, their peers and references)
    library                the rest of spikejax/: numerics and host-side infrastructure

An import may point down this list, never up: the library imports no robot, no
command and no plotting or argument parsing; a robot's model imports no benchmark
and no peer simulator; nothing installed imports the tests. ``python -m pytest
tests/test_layers.py`` is the check.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
APP = ("spikejax.cli", "spikejax.commands", "spikejax.benchmarking")
PLOTTING_AND_PEERS = ("matplotlib", "argparse", "skimage", "cv2", "brian2", "nest", "tqdm.contrib")


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every module a file imports, relative imports resolved."""
    tree = ast.parse(path.read_text(), str(path))
    package = _module(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def _under(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _is_app(path: Path) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return (
        rel == "spikejax/cli.py"
        or rel.startswith(("spikejax/commands/", "benchmarks/"))
        or rel == "spikejax/benchmarking.py"
        or (rel.startswith("robots/") and path.name.startswith(("reproduce", "bench")))
    )


FILES = sorted(p for d in ("spikejax", "robots", "benchmarks") for p in (ROOT / d).rglob("*.py"))


def _violations(path: Path) -> list[str]:
    rel = path.relative_to(ROOT).as_posix()
    bad = []
    for name in sorted(_imports(path)):
        if _under(name, ("tests",)):
            bad.append(f"{rel} imports the tests ({name})")
        if rel.startswith("spikejax/") and _under(name, ("robots", "benchmarks")):
            bad.append(f"{rel}: the library imports {name}")
        if not _is_app(path) and _under(name, APP + ("benchmarks",)):
            bad.append(f"{rel}: a model imports the app layer ({name})")
        if not _is_app(path) and path.name != "peers.py" and _under(name, PLOTTING_AND_PEERS):
            bad.append(f"{rel}: a model imports {name} (plotting, argument parsing and peers belong to apps)")
    return bad


@pytest.mark.parametrize("path", FILES, ids=[p.relative_to(ROOT).as_posix() for p in FILES])
def test_imports_point_down_the_layers(path):
    assert _violations(path) == []


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    fake = ROOT / "spikejax" / "_layers_probe.py"
    monkeypatch.setattr(Path, "read_text", lambda self: "from robots.snake import env\nimport matplotlib.pyplot\n")
    assert _violations(fake) == [
        "spikejax/_layers_probe.py: a model imports matplotlib.pyplot (plotting, argument parsing and peers belong to apps)",
        "spikejax/_layers_probe.py: the library imports robots.snake",
        "spikejax/_layers_probe.py: the library imports robots.snake.env",
    ]
