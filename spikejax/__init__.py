"""spikejax: batched spiking neural networks that control robots, in JAX."""

from spikejax.coding import (
    DecoderParams,
    DecoderState,
    decoder_init,
    decoder_step,
    poisson_spikes,
    poisson_train,
    shift_scale,
)
from spikejax.neurons import (
    DiscreteLIFParams,
    DiscreteLIFState,
    LIFParams,
    LIFState,
    discrete_lif_init,
    discrete_lif_step,
    lif_first_spike_time,
    lif_init,
    lif_params,
    lif_rate,
    lif_step,
)

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
