"""spikejax: batched spiking neural networks that control robots, in JAX."""

from spikejax.neurons import DiscreteLIFParams
from spikejax.neurons import DiscreteLIFState
from spikejax.neurons import discrete_lif_init
from spikejax.neurons import discrete_lif_step
from spikejax.neurons import LIFParams
from spikejax.neurons import LIFState
from spikejax.neurons import lif_params
from spikejax.neurons import lif_init
from spikejax.neurons import lif_step
from spikejax.neurons import lif_rate
from spikejax.neurons import lif_first_spike_time
from spikejax.coding import DecoderParams
from spikejax.coding import DecoderState
from spikejax.coding import decoder_init
from spikejax.coding import decoder_step
from spikejax.coding import poisson_spikes
from spikejax.coding import poisson_train
from spikejax.coding import shift_scale

__version__ = "0.1.0"

__all__ = [
    "DiscreteLIFParams",
    "DiscreteLIFState",
    "discrete_lif_init",
    "discrete_lif_step",
    "LIFParams",
    "LIFState",
    "lif_params",
    "lif_init",
    "lif_step",
    "lif_rate",
    "lif_first_spike_time",
    "DecoderParams",
    "DecoderState",
    "decoder_init",
    "decoder_step",
    "poisson_spikes",
    "poisson_train",
    "shift_scale",
]
