"""Event vision: event streams, the DVS emulator, spiking Hough grids, pipe geometry."""

from spikejax.vision.events import Events, compact, empty
from spikejax.vision.hough import CircleGrid, LineGrid, hough_params
from spikejax.vision.io import Recording, from_structured, to_structured
from spikejax.vision.pipe import Pipe, find_body, find_entry, track, track_params

__all__ = [
    "Events",
    "compact",
    "empty",
    "LineGrid",
    "CircleGrid",
    "hough_params",
    "Recording",
    "from_structured",
    "to_structured",
    "Pipe",
    "find_body",
    "find_entry",
    "track",
    "track_params",
]
