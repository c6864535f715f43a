"""Event vision: event streams, the DVS emulator, spiking Hough grids, pipe geometry."""

from spikejax.vision.events import Events
from spikejax.vision.events import compact
from spikejax.vision.events import empty
from spikejax.vision.hough import CircleGrid
from spikejax.vision.hough import LineGrid
from spikejax.vision.hough import hough_params
from spikejax.vision.io import Recording
from spikejax.vision.io import from_structured
from spikejax.vision.io import to_structured
from spikejax.vision.pipe import Pipe
from spikejax.vision.pipe import find_body
from spikejax.vision.pipe import find_entry
from spikejax.vision.pipe import track
from spikejax.vision.pipe import track_params

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
