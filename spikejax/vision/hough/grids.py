"""The Hough parameter spaces of the snake pipe-tracking paper: Eq. (2) for lines, Eq. (3) for circles.

Each grid is a static, hashable configuration (a frozen dataclass; a change
recompiles). The wiring of the input layer, which cells an event at pixel
``(x, y)`` votes for, is computed once per grid on the host in float64:
`line_table` for lines, `ring_offsets` for circles.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from spikejax.errors import UserError

__all__ = ["LineGrid", "CircleGrid", "Grid", "line_table", "ring_offsets"]


def _round_half_away(v: np.ndarray) -> np.ndarray:
    """C's ``round``: nearest integer, ties away from zero (what scikit-image uses)."""
    r = np.rint(v)
    tie = np.abs(v - np.trunc(v)) == 0.5
    return np.where(tie, np.trunc(v) + np.sign(v), r)


@dataclasses.dataclass(frozen=True)
class LineGrid:
    """The (theta, rho) parameter space of Eq. (2) of the snake pipe-tracking paper.

    Attributes:
        width, height: sensor size, pixels.
        n_theta: angles ``theta_k = k * 180 / n_theta`` degrees (180: 1 degree).
        n_rho: rho bins.
        rho_step: bin width, pixels. Bin ``j`` holds the rho that round to
            ``(j - rho_offset) * rho_step`` (ties away from zero).
        origin: ``(ox, oy)``, the pixel the distances are measured from. Default
            ``(width / 2, height / 2)``: then ``|rho| <= 90`` on a 128 x 128
            sensor and the paper's 180 bins of 1 pixel hold every line.
        rho_offset: bin of ``rho = 0``; default ``n_rho // 2``.
        merge_pixels: how the votes are computed, not what they are: sum a
            slot's events per pixel (signed by polarity) before voting, so that
            each active pixel votes once with its total and pixels whose events
            cancel do not vote. The accumulator is linear in the events, so it
            is the same, exactly. Pays when pixels repeat within a slot (long
            slots of a real sensor); costs ~10 % when every event has a pixel
            of its own (docs/BENCHMARKS.md, "Spiking Hough detectors").

    Votes that fall outside the bins are dropped (with the defaults on a
    128 x 128 sensor only the corner pixel ``(0, 0)`` at 44-46 degrees, where
    ``rho = -90.5``).
    """

    width: int = 128
    height: int = 128
    n_theta: int = 180
    n_rho: int = 180
    rho_step: float = 1.0
    origin: tuple[float, float] | None = None
    rho_offset: int | None = None
    merge_pixels: bool = False

    def __post_init__(self):
        if not isinstance(self.merge_pixels, (bool, np.bool_)):
            raise UserError(f"LineGrid.merge_pixels must be True or False, not {self.merge_pixels!r}")
        for name in ("width", "height", "n_theta", "n_rho"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value > 0):
                raise UserError(f"LineGrid.{name} must be a positive integer, not {value!r}")
        if not self.rho_step > 0:
            raise UserError(f"LineGrid.rho_step must be > 0 pixels, not {self.rho_step!r}")
        if self.origin is None:
            object.__setattr__(self, "origin", (self.width / 2, self.height / 2))
        else:
            object.__setattr__(self, "origin", tuple(float(o) for o in self.origin))
        if self.rho_offset is None:
            object.__setattr__(self, "rho_offset", self.n_rho // 2)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_theta, self.n_rho)

    @property
    def size(self) -> int:
        return self.n_theta * self.n_rho

    def thetas(self) -> np.ndarray:
        """Angles of the rows, radians, ``(n_theta,)``."""
        return np.arange(self.n_theta) * (np.pi / self.n_theta)

    def rhos(self) -> np.ndarray:
        """Centre of each rho bin, pixels, ``(n_rho,)``."""
        return (np.arange(self.n_rho) - self.rho_offset) * self.rho_step

    def skimage_thetas(self) -> np.ndarray:
        """The angles to give `skimage.transform.hough_line` for the same lines.

        scikit-image writes ``rho = x cos(phi) + y sin(phi)`` from the top-left
        pixel, Eq. (2) writes ``rho = x sin(theta) + y cos(theta)``: the same line
        has ``phi = pi / 2 - theta``. With ``origin=(0, 0)``, ``rho_step=1`` and
        ``rho_offset = ceil(hypot(height, width))`` (``n_rho = 2 rho_offset + 1``),
        row ``k`` of our accumulator is column ``k`` of scikit-image's, bin for bin.
        """
        return np.pi / 2 - self.thetas()

    def cell(self, theta: float, rho: float) -> tuple[int, int]:
        """``(theta_index, rho_index)`` of the cell nearest to a line (radians, pixels).

        ``theta`` is taken modulo pi (``(theta + pi, -rho)`` is the same line).
        """
        theta = float(theta) % (2 * np.pi)
        if theta >= np.pi:
            theta, rho = theta - np.pi, -rho
        k = int(round(theta / (np.pi / self.n_theta)))
        if k == self.n_theta:
            k, rho = 0, -rho
        j = int(_round_half_away(np.asarray(rho / self.rho_step))) + self.rho_offset
        return k, j

    def line(self, theta_index, rho_index) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, rho)`` (radians, pixels) of cells given by their indices."""
        theta_index = np.asarray(theta_index)
        rho_index = np.asarray(rho_index)
        return theta_index * (np.pi / self.n_theta), (rho_index - self.rho_offset) * self.rho_step


@dataclasses.dataclass(frozen=True)
class CircleGrid:
    """The (a, b, r) parameter space of Eq. (3) of the snake pipe-tracking paper.

    Attributes:
        width, height: sensor size, pixels; the centres ``(a, b)`` are its pixels.
        n_r: radii ``r_k = r_min + k * r_step``.
        r_min: smallest radius, pixels.
        r_step: radius step, pixels.

    An event at ``(x, y)`` votes for ``(a, b, r_k)`` when its distance to the
    centre rounds to ``r_k`` in steps of ``r_step``:
    ``round((hypot(x - a, y - b) - r_min) / r_step) == k`` (ties away from zero).
    """

    width: int = 128
    height: int = 128
    n_r: int = 64
    r_min: float = 1.0
    r_step: float = 1.0

    def __post_init__(self):
        for name in ("width", "height", "n_r"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value > 0):
                raise UserError(f"CircleGrid.{name} must be a positive integer, not {value!r}")
        if not self.r_min > 0:
            raise UserError(f"CircleGrid.r_min must be > 0 pixels, not {self.r_min!r}")
        if not self.r_step > 0:
            raise UserError(f"CircleGrid.r_step must be > 0 pixels, not {self.r_step!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.n_r, self.height, self.width)

    @property
    def size(self) -> int:
        return self.n_r * self.height * self.width

    def radii(self) -> np.ndarray:
        """Radius of each plane, pixels, ``(n_r,)``."""
        return self.r_min + np.arange(self.n_r) * self.r_step

    def r_max(self) -> float:
        """Largest distance that still votes, pixels."""
        return self.r_min + (self.n_r - 0.5) * self.r_step


Grid = LineGrid | CircleGrid


def check_grid(grid) -> None:
    """Refuse anything that is not a `LineGrid` or a `CircleGrid`."""
    if not isinstance(grid, (LineGrid, CircleGrid)):
        raise UserError(f"not a Hough grid: {type(grid).__name__}")


@functools.cache
def line_table(grid: LineGrid) -> np.ndarray:
    """Which cell each pixel votes for at each angle: ``(height * width, n_theta)`` int32.

    Entry ``[y * width + x, k]`` is the flat cell index ``k * n_rho + j`` of the rho
    bin ``j`` of pixel ``(x, y)`` at ``theta_k``, or ``grid.size`` when the bin is
    outside the grid. Computed once per grid in float64, with the trigonometric
    values of `LineGrid.skimage_thetas`, so that it agrees with scikit-image bin
    for bin.
    """
    phi = grid.skimage_thetas()
    sin_t, cos_t = np.cos(phi), np.sin(phi)  # sin(theta), cos(theta)
    y, x = np.divmod(np.arange(grid.height * grid.width), grid.width)
    ox, oy = grid.origin
    rho = (x[:, None] - ox) * sin_t[None, :] + (y[:, None] - oy) * cos_t[None, :]
    if grid.rho_step != 1.0:
        rho = rho / grid.rho_step
    j = _round_half_away(rho).astype(np.int64) + grid.rho_offset
    inside = (j >= 0) & (j < grid.n_rho)
    flat = np.arange(grid.n_theta)[None, :] * grid.n_rho + j
    return np.where(inside, flat, grid.size).astype(np.int32)


@functools.cache
def ring_offsets(grid: CircleGrid) -> np.ndarray:
    """The cells one event votes for, as offsets: ``(m, 3)`` int32 rows ``(k, db, da)``.

    An event at ``(x, y)`` votes for centre ``(x + da, y + db)`` at radius index
    ``k`` (the rings of `CircleGrid`); ordered by ``k``, then ``db``, ``da``.
    """
    reach = int(math.floor(grid.r_max()))
    d = np.arange(-reach, reach + 1)
    db, da = np.meshgrid(d, d, indexing="ij")
    k = _round_half_away((np.hypot(da, db) - grid.r_min) / grid.r_step)
    rows = []
    for i in range(grid.n_r):
        sel = k == i
        rows.append(np.stack([np.full(sel.sum(), i), db[sel], da[sel]], axis=1))
    return np.concatenate(rows).astype(np.int32)
