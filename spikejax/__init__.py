"""spikejax: batched spiking neural networks that control robots, in JAX."""

from spikejax.neurons import DiscreteLIFParams
from spikejax.neurons import DiscreteLIFState
from spikejax.neurons import discrete_lif_init
from spikejax.neurons import discrete_lif_step

__version__ = "0.1.0"

__all__ = [
    "DiscreteLIFParams",
    "DiscreteLIFState",
    "discrete_lif_init",
    "discrete_lif_step",
]
