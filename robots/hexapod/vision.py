"""The hexapod's visual SNN: the paper's window-to-gait wiring on `spikejax.vision.edges` (Sec. IV-C, V-A).

The layers (filter, edge windows, window confirmation) are the library's; what is
the hexapod's is the readout onto its three gait-selection neurons (the order
of `robots.hexapod.gaits.GAIT_NAMES`):

* G1, forward, from the **upper 5 window rows** (5 x 12 = 60 layer-3 neurons, the
  paper's neurons 1-60: an object high in the image is far) at weight 0.4;
* G2, left turn, from the **lower 3 rows, left 6 columns** (18 neurons) at 0.7;
* G3, right turn, from the **lower 3 rows, right 6 columns** (18 neurons) at 0.7.

60 + 18 + 18 = 96 is Sec. V-A's numbering; Fig. 6(e)'s "upper half" would be 48
(errata E4 of the reading notes), so the 60 / 18 / 18 split is followed. Both
branches (vertical and horizontal edges) drive the gait neurons with the same
map (Fig. 7 shows the vertical one; the text says the horizontal one behaves
alike). Image column 0 is the left of the view, so an object low and to the left
is near on the left and turns the robot left (G2, as Fig. 2 names it; Sec. V-A
once calls G2 the right turn, errata E7).

The weights make G1 need three coincident window spikes (1.2 > 1) and a turn
two (1.4 > 1): the higher weight "gives preference to closer objects", the
nearest-prey mechanism.

**Wirings** (`WIRINGS`). ``"paper"`` is the readout above and nothing else.
``"near-veto"``, the default (`WIRING`), adds one inhibitory synapse from each
near window (the turn regions) to G1 at ``NEAR_VETO`` (-3.2: one near
window's spike outweighs eight far ones at 0.4). With the paper's wiring a
near prey still lights far windows above it: a cube's events lie on both
sides of the near/far row until its top has crossed (about 0.5 m of depth
for the 0.03 m cube against 0.70 m for its base), so G1, fed by 60 windows,
out-counts the turn (7-15 spikes a step against 1-7) and a prey aside
leaves the view before the robot turns. Measured on the same 500
single-prey episodes (`spikejax reproduce hexapod-prey`, seed 0): capture
0.890 with the paper's wiring, 0.910 / 0.936 / 0.954 / 0.954 / 0.960 with
-0.4 / -0.8 / -3.2 / -6.4 / -12.8, against 0.964 for the windows' rule fed the
truth (`robots.hexapod.controllers.oracle_in_view`); on the 2,000 open-loop
scenes one near prey among far ones is decided right in 98.4 % instead of
74.8 %. The inhibition is the paper's own aim, "preference to closer
objects", made a synapse.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.vision import edges

__all__ = [
    "FORWARD",
    "LEFT",
    "NEAR_VETO",
    "PAPER_SENSOR",
    "RIGHT",
    "WIRING",
    "WIRINGS",
    "check_wiring",
    "regions",
    "readout",
    "scaled_config",
    "vision_params",
]

# The CeleX-V DVS of Sec. IV: 800 x 1280 pixels in 100 x 100 windows, three gait-selection neurons.
PAPER_SENSOR = edges.EdgeConfig(height=800, width=1280, window=100, n_out=3)
FORWARD, LEFT, RIGHT = 0, 1, 2
_FAR_ROWS = 5 / 8  # Sec. V-A: 60 of the 96 windows (5 of 8 rows) drive G1
WIRINGS = ("near-veto", "paper")
WIRING = "near-veto"
NEAR_VETO = -3.2  # near window -> G1 in the "near-veto" wiring (module docstring)


def check_wiring(wiring: str) -> str:
    """``wiring`` if it is one of `WIRINGS`, else a one-line `UserError`."""
    if wiring not in WIRINGS:
        raise UserError(f"unknown wiring {wiring!r}; expected one of {', '.join(WIRINGS)}")
    return wiring


def regions(config: edges.EdgeConfig) -> np.ndarray:
    """Which gait neuron each window drives, ``(n_rows, n_cols)`` int: `FORWARD`, `LEFT` or `RIGHT`.

    The upper ``round(5 / 8 n_rows)`` rows are far (forward); the rows below are
    near, their left half (columns ``< n_cols / 2``) left, their right half right.
    An odd number of window columns gives the middle column to neither turn: it
    stays silent.
    """
    if config.n_rows < 2 or config.n_cols < 2:
        raise UserError(f"the gait map needs at least 2 x 2 windows, got {config.n_rows} x {config.n_cols}")
    far = max(1, min(config.n_rows - 1, round(_FAR_ROWS * config.n_rows)))
    region = np.full((config.n_rows, config.n_cols), -1, np.int32)
    region[:far] = FORWARD
    half = config.n_cols // 2
    region[far:, :half] = LEFT
    region[far:, config.n_cols - half :] = RIGHT
    return region


def readout(config: edges.EdgeConfig, forward=0.4, turn=0.7, near_forward=0.0) -> jnp.ndarray:
    """Layer 3 -> gait-selection weights ``(3, n_rows, n_cols, 2)``, both branches.

    Sec. IV-C's 0.4 (far windows -> G1) and 0.7 (near windows -> G2, G3), and
    ``near_forward`` from every near window to G1 (0 in the paper; `NEAR_VETO`
    in the ``"near-veto"`` wiring).
    """
    if config.n_out != 3:
        raise UserError(f"the hexapod has 3 gait-selection neurons, the config {config.n_out}")
    region = regions(config)
    w = np.zeros((3, config.n_rows, config.n_cols, 2), np.float32)
    for gait, weight in ((FORWARD, forward), (LEFT, turn), (RIGHT, turn)):
        w[gait][region == gait] = weight
    w[FORWARD][(region == LEFT) | (region == RIGHT)] = near_forward
    return jnp.asarray(w)


def scaled_config(height: int, width: int, window: int) -> edges.EdgeConfig:
    """A smaller sensor with the paper's 8 x 12 (or any) windows, for statistics on a CPU."""
    return edges.EdgeConfig(height=height, width=width, window=window, n_out=3)


def vision_params(config: edges.EdgeConfig = PAPER_SENSOR, wiring: str = WIRING, **overrides) -> edges.EdgeParams:
    """The paper's layers for ``config``: its weights at 100-pixel windows, re-derived for smaller ones.

    ``wiring`` (`WIRINGS`) picks the readout: the paper's, or with the near
    windows' veto on G1 (the module's notes).

    At the paper's size layer 2 needs 17 of a window column's 100 filter spikes
    (0.06 each) and layer 3 four of its window's layer-2 spikes (0.3). A window of
    ``n`` pixels keeps the fractions: ``ceil(17 n / 100)`` spikes for layer 2 and
    ``max(1, ceil(4 n / 100))`` for layer 3, each weight set halfway,
    ``1 / (k - 1/2)``, so that ``k`` spikes fire and ``k - 1`` do not (at 100
    pixels the paper's own weights are kept). ``overrides`` go to
    `spikejax.vision.edges.edge_params`.
    """
    if config.window == 100:
        column, window = 0.06, 0.3
    else:
        column = 1.0 / (math.ceil(17 * config.window / 100) - 0.5)
        window = 1.0 / (max(1, math.ceil(4 * config.window / 100)) - 0.5)
    kwargs = dict(column=column, window=window)
    kwargs.update(overrides)
    near_forward = NEAR_VETO if check_wiring(wiring) == "near-veto" else 0.0
    return edges.edge_params(readout(config, near_forward=near_forward), **kwargs)
