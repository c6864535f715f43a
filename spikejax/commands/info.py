"""``spikejax info``: versions and devices."""

from __future__ import annotations

from spikejax.commands import Command


def _add_arguments(parser) -> None:
    del parser


def run() -> int:
    """Print spikejax's and JAX's versions and JAX's devices."""
    import jax

    import spikejax

    print(f"spikejax {spikejax.__version__}")
    print(f"jax {jax.__version__}, devices: {', '.join(str(d) for d in jax.devices())}")
    return 0


command = Command(help="versions and devices", add_arguments=_add_arguments, run=run)
