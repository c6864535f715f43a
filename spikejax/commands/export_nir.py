"""``spikejax export nir --weights FILE --out GRAPH.nir``: a saved network as a NIR graph.

The robots' exporters (`spikejax.nir.NIRExporter`) are registered as entry
points of the group ``spikejax.nir``, as commands are; the command asks each
whether it recognises the weights file (or takes the one ``--robot`` names),
exports one seed (``--seed``) or every seed of the file, and writes the graph
in NIR's HDF5 format, atomically.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path

from spikejax.commands import Command
from spikejax.errors import UserError

GROUP = "spikejax.nir"


def exporters() -> dict:
    """The registered NIR exporters, by name (robot packages register them under `GROUP`)."""
    return {point.name: point.load() for point in entry_points(group=GROUP)}


def _add_arguments(parser) -> None:
    parser.add_argument("--weights", required=True, help="a saved network (.npz: a snake-rstdp weights file, ...)")
    parser.add_argument("--out", required=True, help="the NIR graph to write (GRAPH.nir)")
    parser.add_argument("--robot", default=None, help="which robot's network (default: recognised from the file)")
    parser.add_argument("--seed", type=int, default=None, help="export this seed of the file (default: every seed)")


def _pick(path: Path, robot: str | None):
    import numpy as np

    found = exporters()
    if robot is not None:
        if robot not in found:
            raise UserError(f"--robot {robot}: no such exporter (registered: {', '.join(sorted(found)) or 'none'})")
        return found[robot]
    try:
        with np.load(path) as z:
            keys = list(z.files)
            matches = [e for e in found.values() if e.recognises(keys, z)]
    except (OSError, ValueError) as e:
        raise UserError(f"--weights {path}: not an .npz weights file ({e.__class__.__name__})") from None
    if len(matches) != 1:
        what = "no" if not matches else "more than one"
        raise UserError(f"--weights {path}: {what} exporter recognises the file; say which with --robot")
    return matches[0]


def run(*, weights: str, out: str, robot: str | None, seed: int | None) -> int:
    """Export the network saved in ``weights`` to the NIR graph ``out``."""
    from spikejax import nir

    path, out_path = Path(weights), Path(out)
    if not path.is_file():
        raise UserError(f"--weights {path}: no such file")
    if out_path.is_dir():
        raise UserError(f"--out {out_path}: is a directory; give a file name (GRAPH.nir)")
    if not out_path.parent.is_dir():
        raise UserError(f"--out {out_path}: the directory {out_path.parent} does not exist")
    exporter = _pick(path, robot)
    graph = exporter.export(path, seed)
    tmp = out_path.with_name(out_path.name + ".tmp")
    nir.write(tmp, graph)
    tmp.replace(out_path)
    neurons = sum(int(node.v_threshold.size) for node in graph.nodes.values() if hasattr(node, "v_threshold"))
    seeds = graph.metadata.get(nir.KEY, {}).get("seeds", [])
    print(
        f"wrote {out_path}: {exporter.name}, seeds {', '.join(str(int(s)) for s in seeds)}, "
        f"{len(graph.nodes)} nodes, {neurons} neurons"
    )
    return 0


command = Command(
    help="a saved network (RoboBee, snake, hexapod weights) as a NIR graph for other simulators and chips",
    add_arguments=_add_arguments,
    run=run,
)
