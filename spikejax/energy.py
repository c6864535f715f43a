"""Energy of a spiking network on neuromorphic hardware, estimated from its spike counts.

The hexapod SCPG paper (Sec. V-C) estimates its system's energy by counting
spikes and charging each the 1.7 nJ that Intel's Loihi spends per spike (its
reference [22]): ``E = N_spikes x 1.7 nJ`` per layer. `spike_energy` does that
for any counts; `LOIHI_J_PER_SPIKE` is the paper's figure, and other chips'
costs can be passed instead.

The paper's own numbers, recomputed (`PAPER_HEXAPOD`): about 1.5 million
events in the filter layer per forward step give 1.5e6 x 1.7 nJ = 2.55 mJ,
and 7 CPG spikes 7 x 1.7 nJ = 11.9 nJ, so a step costs about 2.55 mJ, which
the paper then calls "overall sub-mJ": it is not. Its 1.5 million "events"
from a layer of 1.024 million neurons (1.46 per neuron per step) are more
likely the DVS events entering the filter than the filter's spikes, so the
estimate here keeps input events and spikes apart.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from spikejax.errors import UserError

__all__ = ["LOIHI_J_PER_SPIKE", "PAPER_HEXAPOD", "spike_energy"]

# Sec. V-C of the hexapod SCPG paper, after its reference [22] (Intel Loihi).
LOIHI_J_PER_SPIKE = 1.7e-9

# The counts behind the paper's estimate (Sec. V-C): per forward step of the robot.
PAPER_HEXAPOD = {"filter": 1.5e6, "cpg": 7}


def spike_energy(counts: Mapping[str, float], joules_per_spike: float = LOIHI_J_PER_SPIKE) -> dict[str, float]:
    """Joules per layer, ``count x joules_per_spike``, and their ``"total"``.

    Args:
        counts: spikes per layer (a number or an array, summed), e.g.
            ``{"filter": ..., "layer2": ..., "cpg": ...}``.
        joules_per_spike: the chip's cost of one spike, J (default Loihi's 1.7 nJ).

    Raises:
        UserError: in one line, for a negative or non-finite count or cost, or a
            layer named ``"total"``.
    """
    if not np.isfinite(joules_per_spike) or joules_per_spike < 0:
        raise UserError(f"joules_per_spike must be a finite number >= 0, got {joules_per_spike!r}")
    energy = {}
    for layer, count in counts.items():
        if layer == "total":
            raise UserError("'total' is the sum spike_energy adds; name the layer otherwise")
        n = float(np.sum(np.asarray(count, np.float64)))
        if not np.isfinite(n) or n < 0:
            raise UserError(f"the spike count of {layer!r} must be finite and >= 0, got {n!r}")
        energy[layer] = n * joules_per_spike
    energy["total"] = float(sum(energy.values()))
    return energy
