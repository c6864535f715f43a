"""Event vision: event streams, the DVS emulator, spiking Hough grids, pipe geometry."""

from spikejax.vision.events import Events
from spikejax.vision.events import compact
from spikejax.vision.events import empty

__all__ = ["Events", "compact", "empty"]
