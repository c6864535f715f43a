"""Leg numbering and the three gait patterns of the hexapod SCPG (Fig. 2 of the paper).

Leg numbering, written down once. CPG neuron ``N_k`` drives leg ``k``; index
``k - 1`` in every array::

            front
       N1 o-------o N4
          |       |
       N2 o  body o N5
          |       |
       N3 o-------o N6
            hind
       left        right

With this numbering the paper's tripod (Sec. III-B: "N2,4,6 fire in the first
time step and N1,3,5 spike in the next") alternates the two tripods {L2, R1, R3}
and {L1, L3, R2}, as a walking insect does.

The paper's Fig. 2(b) shows the turning gaits only as rasters and says "for
turning left, neurons of the right side of the hexapod fire and vice-versa". We
take the left turn to be the tripod restricted to the right side (the left legs
stay planted and the robot pivots towards them), and the right turn to be its
mirror image (N1 <-> N4, N2 <-> N5, N3 <-> N6).

- G1, tripod (forward): {N2, N4, N6} -> {N1, N3, N5} -> ...
- G2, left turn (right legs step): {N4, N6} -> {N5} -> ...
- G3, right turn (left legs step): {N1, N3} -> {N2} -> ...

Every pattern can be produced by the network, which has no self-connections: a
phase of a single neuron that would have to fire at step 1 from the tonic
gait input and then fall silent at step 2 under the very same input could not
be (``{N2} -> {N1, N3}`` for G3 is such a case), so no phase starts with one.

The paper's text swaps G2 and G3 once (Sec. V-A calls G2 the right turn); we
follow Fig. 2.
"""

from __future__ import annotations

import numpy as np

N_LEGS = 6
N_GAITS = 3
PERIOD = 2

LEG_NAMES = ("L1", "L2", "L3", "R1", "R2", "R3")
GAIT_NAMES = ("G1 tripod", "G2 left turn", "G3 right turn")


def _phases(*phases: tuple[int, ...]) -> np.ndarray:
    """Spike sets given with the paper's 1-based neuron numbers -> 0/1 array (PERIOD, N_LEGS)."""
    out = np.zeros((len(phases), N_LEGS), np.float32)
    for t, neurons in enumerate(phases):
        out[t, [n - 1 for n in neurons]] = 1.0
    return out


# PATTERNS[g, t] is the set of CPG neurons that must fire at step t + 1, t + 1 + PERIOD, ...
# after gait-selection neuron G(g+1) is switched on from rest.
PATTERNS = np.stack(
    [
        _phases((2, 4, 6), (1, 3, 5)),  # G1 tripod
        _phases((4, 6), (5,)),  # G2 left turn: right legs
        _phases((1, 3), (2,)),  # G3 right turn: left legs, mirror of G2
    ]
)


def required_spikes(gait: int, n_steps: int) -> np.ndarray:
    """The required CPG raster of ``gait`` (0-based) for ``n_steps`` steps from rest, shape (n_steps, 6)."""
    return PATTERNS[gait][np.arange(n_steps) % PERIOD]
