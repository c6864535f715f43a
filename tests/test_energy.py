"""`spikejax.energy`: the hexapod paper's Sec. V-C arithmetic, and counts from the visual SNN."""

import jax.numpy as jnp
import numpy as np
import pytest

from spikejax import energy
from spikejax.errors import UserError


def test_the_papers_own_figures():
    """1.5e6 x 1.7 nJ = 2.55 mJ for the filter layer; 7 x 1.7 nJ = 11.9 nJ for the CPG; ~2.55 mJ a step, not sub-mJ."""
    e = energy.spike_energy(energy.PAPER_HEXAPOD)
    assert e["filter"] == pytest.approx(2.55e-3, rel=1e-12)
    assert e["cpg"] == pytest.approx(11.9e-9, rel=1e-12)
    assert e["total"] == pytest.approx(2.55e-3 + 11.9e-9, rel=1e-12) and e["total"] > 1e-3
    # A tonic gait-selection neuron adds one spike a step: 8 spikes, 13.6 nJ.
    assert energy.spike_energy({"cpg": 8})["cpg"] == pytest.approx(13.6e-9, rel=1e-12)


def test_counts_arrays_are_summed_and_another_chip_can_be_charged():
    e = energy.spike_energy({"windows": jnp.ones((8, 12, 2), jnp.int32), "out": np.array([3, 0, 1])}, 2e-9)
    assert e["windows"] == pytest.approx(192 * 2e-9) and e["out"] == pytest.approx(8e-9)
    assert e["total"] == pytest.approx(196 * 2e-9)


@pytest.mark.parametrize(
    "counts, cost, words",
    [
        ({"a": -1}, 1e-9, "'a'"),
        ({"a": np.nan}, 1e-9, "'a'"),
        ({"a": 1}, -1.0, "joules_per_spike"),
        ({"total": 1}, 1e-9, "total"),
    ],
)
def test_bad_counts_are_one_line_errors(counts, cost, words):
    with pytest.raises(UserError, match=words) as info:
        energy.spike_energy(counts, cost)
    assert "\n" not in str(info.value)
