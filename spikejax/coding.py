"""Encoders that turn continuous signals into spikes, the pre-processing before them, and decoders.

Every function is written for one population (no batch axis: ``jax.vmap`` adds it)
and takes an explicit ``jax.random`` key where it is stochastic, keyword-only and
last (``*, key``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError

if TYPE_CHECKING:
    from spikejax.vision.events import Events

__all__ = [
    "DecoderParams",
    "DecoderState",
    "antagonist_currents",
    "antagonist_rates",
    "d_norm",
    "decoder_init",
    "decoder_step",
    "direction_step",
    "event_grid_counts",
    "grid_counts",
    "grid_rates",
    "poisson_counts",
    "PoissonCDF",
    "poisson_cdf",
    "poisson_cdf_counts",
    "poisson_count_train",
    "poisson_spikes",
    "poisson_train",
    "shift_scale",
]


def poisson_spikes(rates: jax.Array, dt, *, key: jax.Array) -> jax.Array:
    """One time step of independent Poisson spike generators.

    Each neuron spikes with probability ``p = 1 - exp(-rate dt)``, the exact
    probability that a Poisson process of that rate has at least one event in a
    window of length ``dt``. The snake R-STDP paper drives its input layer with
    such Poisson neurons (Section II-B, D).

    Args:
        rates: firing rates, Hz, shape ``(n,)`` (any shape works); negative rates
            are treated as 0.
        dt: step length, s (scalar, may be traced).
        key: PRNG key, used once.

    Returns:
        Spikes as a bool array of the shape of ``rates``.

    Notes:
        ``1 - exp(-rate dt)`` rather than ``rate dt`` clipped to 1: both agree to
        ``O((rate dt)^2)`` when ``rate dt << 1``, but the clipped form is no
        longer a probability of anything once ``rate dt`` approaches 1 and
        saturates abruptly, whereas this one bins a true Poisson process: the
        mean count over ``n`` steps is ``n (1 - exp(-rate dt))``, below
        ``rate n dt`` only by the events that fell into an already-occupied step.

    Examples:
        >>> s = poisson_spikes(jnp.full((4,), 100.0), 1e-3, key=jax.random.key(0))
        >>> s.shape, s.dtype
        ((4,), dtype('bool'))
    """
    rates = jnp.asarray(rates)
    dtype = rates.dtype if jnp.issubdtype(rates.dtype, jnp.floating) else jnp.float32
    p = -jnp.expm1(-jnp.maximum(rates, 0.0) * dt)
    return jax.random.uniform(key, rates.shape, dtype) < p


def poisson_train(rates: jax.Array, dt, n_steps: int, *, key: jax.Array) -> jax.Array:
    """A Poisson spike train of ``n_steps`` steps, `poisson_spikes` scanned over time.

    Step ``k`` uses ``jax.random.split(key, n_steps)[k]``, so it equals
    ``poisson_spikes(rates_k, dt, key=keys[k])`` and a simulation that draws its input
    step by step with those keys sees the same train.

    Args:
        rates: firing rates, Hz: shape ``(n,)`` for constant rates or
            ``(n_steps, n)`` for a rate per step.
        dt: step length, s.
        n_steps: number of steps (static: a ``static_argnames`` entry under ``jit``).
        key: PRNG key, used once.

    Returns:
        Spikes, bool, shape ``(n_steps, n)``.

    Raises:
        UserError: if ``rates`` is 2-D and its first axis is not ``n_steps`` long.

    Examples:
        >>> train = poisson_train(jnp.array([0.0, 50.0]), 1e-3, 100, key=jax.random.key(1))
        >>> train.shape, bool(train[:, 0].any())
        ((100, 2), False)
    """
    rates = jnp.asarray(rates)
    keys = jax.random.split(key, n_steps)
    if rates.ndim == 2:
        if rates.shape[0] != n_steps:
            raise UserError(
                f"rates has shape {rates.shape}: a rate per step needs shape (n_steps, n) with n_steps = {n_steps}"
            )

        def step(carry, xs):
            k, r = xs
            return carry, poisson_spikes(r, dt, key=k)

        _, spikes = jax.lax.scan(step, None, (keys, rates))
    else:

        def step(carry, k):
            return carry, poisson_spikes(rates, dt, key=k)

        _, spikes = jax.lax.scan(step, None, keys)
    return spikes


def shift_scale(q: jax.Array, a: jax.Array, b: jax.Array) -> jax.Array:
    """Shifts and scales a signal before encoding, ``q_hat = a (q + b)``.

    The RoboBee paper (Section III) passes ``q_hat_i = a_i (q_i + b_i)``, with
    positive constants ``a_i`` and ``b_i``, into the network instead of each state
    variable ``q_i``, so that states in their expected range give a positive input
    current that makes the input groups fire.

    Args:
        q: signal, any shape.
        a: scale, broadcasting with ``q``.
        b: shift, in the units of ``q``, broadcasting with ``q``.

    Returns:
        ``a * (q + b)``, the broadcast shape.

    Examples:
        >>> float(shift_scale(jnp.float32(-0.5), 2.0, 1.0))
        1.0
    """
    return a * (q + b)


def antagonist_currents(q_hat: jax.Array, n_per_group: int, gain) -> jax.Array:
    """Input currents of groups of neurons split into antagonist halves, one group per signal.

    The RoboBee paper (Section III) feeds each shifted and scaled state variable
    ``q_hat_g`` (`shift_scale`) to its own input group. Here the first
    ``n_per_group // 2`` neurons of group ``g`` get the current ``gain * q_hat_g``
    and the other ``n_per_group - n_per_group // 2`` get ``gain * (1 - q_hat_g)``:
    whichever way ``q_g`` moves, one half of the group is driven harder, so the
    group never falls silent as a whole and a presynaptic learning rule can push
    the output both ways. The halves are this project's addition to the paper's
    encoder (with one-sided groups a large negative error silenced a whole group
    and the RoboBee's SNN flight tumbled); each neuron's own threshold then makes
    it a different rectified feature of ``q_g``.

    Args:
        q_hat: the shifted and scaled signals, shape ``(n_groups,)``.
        n_per_group: neurons per group (static), >= 1; with 1 the group is one
            antagonist neuron.
        gain: current per unit of ``q_hat``, broadcasting with a scalar.

    Returns:
        Currents, shape ``(n_groups * n_per_group,)``, group-major: neuron
        ``n`` belongs to group ``n // n_per_group`` and is antagonist when
        ``n % n_per_group >= n_per_group // 2``.

    Raises:
        UserError: if ``n_per_group`` is not an int >= 1.

    Examples:
        >>> antagonist_currents(jnp.array([0.25, 1.5]), 3, 2.0).tolist()
        [0.5, 1.5, 1.5, 3.0, -1.0, -1.0]
    """
    if isinstance(n_per_group, bool) or not isinstance(n_per_group, int) or n_per_group < 1:
        raise UserError(f"n_per_group must be an int >= 1, got {n_per_group!r}")
    half = n_per_group // 2
    q_hat = jnp.asarray(q_hat)
    drive = jnp.concatenate(
        [jnp.repeat(q_hat[:, None], half, 1), jnp.repeat(1.0 - q_hat[:, None], n_per_group - half, 1)], axis=1
    )
    return gain * drive.reshape(-1)


class DecoderParams(NamedTuple):
    """Parameters of the leaky-integrator decoder, Eq. (8) of the RoboBee paper.

    Attributes:
        alpha: output per unit of the spike trace (the scale ``alpha``), in the
            units of the decoded signal.
        beta: decay rate ``beta`` of each spike's contribution, 1/s, > 0; ``1 / beta``
            trades a faster response for less noise.
        gamma: offset ``gamma``, units of the decoded signal; ``-gamma`` is the
            output of a silent population.
    """

    alpha: jax.Array
    beta: jax.Array
    gamma: jax.Array


class DecoderState(NamedTuple):
    """State of the decoder.

    Attributes:
        trace: ``sum_{t_f < t} exp(beta (t_f - t))`` over all the population's
            spikes, dimensionless, shape ``()``.
    """

    trace: jax.Array


def decoder_init(dtype=jnp.float32) -> DecoderState:
    """The decoder before any spike: a zero trace (output ``-gamma``)."""
    return DecoderState(trace=jnp.zeros((), dtype))


def decoder_step(params: DecoderParams, state: DecoderState, spikes: jax.Array, dt) -> tuple[DecoderState, jax.Array]:
    """One step of the leaky-integrator population decoder, Eq. (8) of the RoboBee paper.

    Eq. (8), ``y_hat(t) = alpha * sum_{t_f < t} exp(beta (t_f - t)) - gamma``, the
    sum running over the spike times ``t_f`` of every neuron of the population,
    is computed exactly by a trace that takes the spikes stamped ``t_k`` (as
    `spikejax.lif_step` stamps them) and decays over the step::

        trace(t_k + dt) = exp(-beta dt) * (trace(t_k) + n_k),
        y_hat(t_k + dt) = alpha * trace(t_k + dt) - gamma,

    ``n_k`` being the number of spikes in the step. A spike at ``t_k`` thus
    contributes ``alpha exp(-beta dt)`` at ``t_k + dt`` (``t_f < t`` is strict).

    Args:
        params: scale, decay rate and offset.
        state: the trace at ``t_k``.
        spikes: the population's spikes of the step from ``t_k``, bool or 0/1, shape ``(n,)``.
        dt: step length, s.

    Returns:
        The state and the decoded output ``y_hat`` at ``t_k + dt``, shape ``()``.

    Notes:
        For a population of ``N`` neurons each spiking with probability ``p``
        per step (rate ``nu ~ p / dt``), the mean output in the steady state is
        ``alpha * N p exp(-beta dt) / (1 - exp(-beta dt)) - gamma``, about
        ``alpha N nu / beta - gamma`` when ``beta dt << 1``.

    Examples:
        >>> p = DecoderParams(alpha=jnp.float32(1.0), beta=jnp.float32(10.0),
        ...                   gamma=jnp.float32(0.0))
        >>> s, y = decoder_step(p, decoder_init(), jnp.array([True, True]), 0.1)
        >>> round(float(y), 4)
        0.7358
    """
    n = jnp.sum(jnp.asarray(spikes, state.trace.dtype))
    decay = jnp.exp(-params.beta * dt)
    trace = (decay * (state.trace + n)).astype(state.trace.dtype)
    return DecoderState(trace=trace), params.alpha * trace - params.gamma


def poisson_counts(rates: jax.Array, dt, *, key: jax.Array) -> jax.Array:
    """One time step of independent Poisson generators that may fire several times a step.

    NEST's ``poisson_generator`` draws, for each target and each step of length
    ``dt``, an independent Poisson number of spikes of mean ``rate dt`` and sends
    them as one spike of that multiplicity. The snake R-STDP paper drives its
    input neurons with such generators (Section II-B, D). Unlike
    `poisson_spikes`, which says only whether a step holds at least one event,
    this keeps the count, so the expected count over a window of length ``T``
    is exactly ``rate T`` at any rate (a cell of Eq. (2) of the snake R-STDP
    paper with ``N`` events then gets ``N`` spikes on average per control step).

    Args:
        rates: rates, Hz, any shape; negative rates are treated as 0.
        dt: step length, s (scalar, may be traced).
        key: PRNG key, used once.

    Returns:
        Counts, int32, the shape of ``rates``: Poisson with mean ``max(rate, 0) dt``.

    Examples:
        >>> n = poisson_counts(jnp.array([0.0, 5e4]), 1e-3, key=jax.random.key(0))
        >>> n.dtype, int(n[0])
        (dtype('int32'), 0)
    """
    rates = jnp.asarray(rates)
    dtype = rates.dtype if jnp.issubdtype(rates.dtype, jnp.floating) else jnp.float32
    lam = jnp.maximum(rates.astype(dtype), 0.0) * dt
    return jax.random.poisson(key, lam, rates.shape, dtype=jnp.int32)


def poisson_count_train(rates: jax.Array, dt, n_steps: int, *, key: jax.Array, max_count: int = 16) -> jax.Array:
    """`poisson_counts` for ``n_steps`` steps of constant rates at once, by inverting the Poisson CDF.

    The generators of the snake R-STDP paper hold their rates for a whole
    control step (200 neural steps), so the CDF ``P(N <= k)``, ``k <
    max_count``, is computed once per rate and each step's count is the number
    of CDF values at or below one uniform draw: no rejection loop
    (``jax.random.poisson`` rejection-samples), and the uniforms come from the
    counter hash `spikejax.random.hash_uniform` seeded by ``key``, a few integer
    operations a number instead of threefry's hundred; both had dominated a
    batched control step. Counts are draws of ``Poisson(rate dt)`` clipped at
    ``max_count``: the clipped mass ``P(N >= max_count)`` is below 1e-9 for means
    ``rate dt`` up to 2 with the default 16 (20 kHz at 0.1 ms; the literal rates
    of Eq. (2) of the snake R-STDP paper reach 18 kHz), and the uniforms'
    24-bit resolution bounds each probability's error by ``2**-24``.

    Args:
        rates: rates, Hz, any shape; negative rates are treated as 0.
        dt: step length, s (scalar, may be traced).
        n_steps: number of steps (static), >= 1.
        key: PRNG key, used once.
        max_count: the largest count drawn (static), >= 1.

    Returns:
        Counts, int32, shape ``(n_steps, *rates.shape)``.

    Examples:
        >>> n = poisson_count_train(jnp.array([0.0, 500.0]), 1e-3, 4000, key=jax.random.key(0))
        >>> n.shape, int(n[:, 0].sum()), 1900 < int(n[:, 1].sum()) < 2100
        ((4000, 2), 0, True)
    """
    n_steps = _static_int("n_steps", n_steps, 1)
    gen = poisson_cdf(rates, dt, key=key, max_count=max_count)
    return jax.vmap(lambda i: poisson_cdf_counts(gen, i))(jnp.arange(n_steps, dtype=jnp.uint32))


class PoissonCDF(NamedTuple):
    """Generators of constant rates as `poisson_count_train` draws them, one step at a time.

    ``cdf``: ``P(N <= k)`` per generator, shape ``(*rates.shape, max_count)``;
    ``seed``: the counter hash's two words. ``poisson_cdf_counts(gen, i)`` is
    row ``i`` of `poisson_count_train`'s result, computed where it is used: a
    neural loop that draws its input inside its step never holds the whole
    ``(n_steps, ...)`` array (in the snake's batched closed loop that array and
    its per-step slices cost more than the draws).
    """

    cdf: jax.Array
    seed: jax.Array


def poisson_cdf(rates: jax.Array, dt, *, key: jax.Array, max_count: int = 16) -> PoissonCDF:
    """The `PoissonCDF` of ``rates`` (Hz, any shape; negative as 0) over steps of ``dt`` s; ``key`` used once."""
    from spikejax.random import hash_seed

    max_count = _static_int("max_count", max_count, 1)
    rates = jnp.asarray(rates)
    dtype = rates.dtype if jnp.issubdtype(rates.dtype, jnp.floating) else jnp.float32
    lam = jnp.maximum(rates.astype(dtype), 0.0) * dt
    k = jnp.arange(1, max_count, dtype=dtype)
    # p_k = e^-lam lam^k / k!, as a running product; cdf[..., j] = P(N <= j)
    terms = jnp.concatenate([jnp.ones(lam.shape + (1,), dtype), jnp.cumprod(lam[..., None] / k, axis=-1)], axis=-1)
    return PoissonCDF(cdf=jnp.exp(-lam)[..., None] * jnp.cumsum(terms, axis=-1), seed=hash_seed(key=key))


def poisson_cdf_counts(gen: PoissonCDF, step) -> jax.Array:
    """The counts (int32, the rates' shape) of step ``step`` (an int, may be traced) of `poisson_cdf`'s generators."""
    from spikejax.random import hash_uniform

    shape = gen.cdf.shape[:-1]
    size = max(1, math.prod(shape))
    counter = jnp.asarray(step, jnp.uint32) * jnp.uint32(size) + jnp.arange(size, dtype=jnp.uint32).reshape(shape)
    u = hash_uniform(gen.seed, counter).astype(gen.cdf.dtype)
    return jnp.sum(u[..., None] >= gen.cdf, axis=-1, dtype=jnp.int32)


def _static_int(name, value, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise UserError(f"{name} must be an int >= {minimum}, got {value!r}")
    return int(value)


def _grid_roi(roi, rows, cols, shape=None):
    """Validated ``(row0, row1, col0, col1), rows, cols`` as Python ints."""
    rows = _static_int("rows", rows, 1)
    cols = _static_int("cols", cols, 1)
    try:
        row0, row1, col0, col1 = roi
    except (TypeError, ValueError):
        raise UserError(f"roi must be (row0, row1, col0, col1), got {roi!r}") from None
    row0, row1, col0, col1 = (_static_int("roi bounds", v, 0) for v in (row0, row1, col0, col1))
    if row1 <= row0 or col1 <= col0:
        raise UserError(f"roi {roi!r} is empty: it needs row0 < row1 and col0 < col1")
    if shape is not None:
        height, width = shape
        if row1 > height or col1 > width:
            raise UserError(f"roi {roi!r} (row0, row1, col0, col1) reaches outside the {height} x {width} frame")
    return (row0, row1, col0, col1), rows, cols


def _cell_one_hot(n_pixels: int, n_cells: int) -> np.ndarray:
    """``(n_pixels, n_cells)`` int32: pixel ``i`` of the ROI lies in cell ``floor(n_cells i / n_pixels)``."""
    cell = (n_cells * np.arange(n_pixels)) // n_pixels
    return (cell[:, None] == np.arange(n_cells)[None, :]).astype(np.int32)


def grid_counts(
    prev_frame: jax.Array,
    frame: jax.Array,
    *,
    threshold,
    roi: tuple[int, int, int, int],
    rows: int = 2,
    cols: int = 5,
    log: bool = False,
    eps: float = 1e-3,
) -> jax.Array:
    """Frame-difference DVS events counted in a ``rows x cols`` grid of a region of interest.

    The input side of Eq. (2) of the snake R-STDP paper: the ``N_event`` of each
    cell of the 2 x 5 grid over the ROI of the DVS frame, both polarities
    together. A pixel ``(x, y)`` has an event when ``|d| >= threshold``, ``d`` the
    difference of the two frames (``log=True``: of their logarithms), exactly as
    `spikejax.vision.dvs.frame_difference` decides (the same float32 arithmetic),
    but the events are counted on the dense difference image: there is no
    capacity, nothing can overflow, and the result equals
    ``event_grid_counts(frame_difference(...)[0], ...)`` whenever that call
    reports no overflow.

    A pixel at column ``x`` and row ``y`` of the ROI falls in the cell of column
    ``c = floor(cols (x - col0) / (col1 - col0))`` and row
    ``r = floor(rows (y - row0) / (row1 - row0))``, so cells differ by at most a
    pixel in width when the ROI's size is not a multiple of the grid's.

    Args:
        prev_frame, frame: ``(height, width)`` intensities in ``[0, 1]``, row ``y``
            and column ``x`` (row 0 at the top), as in `spikejax.vision.events`.
        threshold: smallest change that makes an event (may be traced).
        roi: ``(row0, row1, col0, col1)``, half-open pixel ranges of rows (``y``)
            and columns (``x``), static ints inside the frame.
        rows, cols: grid size (static), >= 1; the paper's grid is 2 x 5.
        log: take the difference of log intensities, ``log(I + eps)``.
        eps: offset inside the logarithm.

    Returns:
        Counts, int32, shape ``(rows * cols,)``, row-major: cell ``(r, c)`` at
        ``r * cols + c`` (row 0 at the top, column 0 on the left).

    Raises:
        UserError: if the frames are not 2-D of one shape, or ``roi``, ``rows``
            or ``cols`` is invalid (empty, outside the frame, not an int).

    Examples:
        >>> prev = jnp.zeros((4, 10))
        >>> grid_counts(prev, prev.at[0, 9].set(1.0), threshold=0.5, roi=(0, 4, 0, 10)).tolist()
        [0, 0, 0, 0, 1, 0, 0, 0, 0, 0]
    """
    prev_frame = jnp.asarray(prev_frame, jnp.float32)
    frame = jnp.asarray(frame, jnp.float32)
    if frame.ndim != 2 or prev_frame.shape != frame.shape:
        raise UserError(f"frames must be 2-D (height, width) of one shape, got {prev_frame.shape} and {frame.shape}")
    (row0, row1, col0, col1), rows, cols = _grid_roi(roi, rows, cols, frame.shape)
    prev_frame = prev_frame[row0:row1, col0:col1]
    frame = frame[row0:row1, col0:col1]
    if log:
        d = jnp.log(frame + eps) - jnp.log(prev_frame + eps)
    else:
        d = frame - prev_frame
    events = jnp.abs(d) >= threshold
    (h, w), (dh, dw) = events.shape, (-(row1 - row0) % rows, -(col1 - col0) % cols)
    if dh == 0 and dw == 0:
        # equal cells: a reshape and a sum fuse with the comparison (under vmap, batched small products did not)
        return events.reshape(rows, h // rows, cols, w // cols).sum(axis=(1, 3), dtype=jnp.int32).reshape(rows * cols)
    # float32 products of 0/1 matrices are exact up to 2**24 events a cell, and run on the BLAS path
    events = events.astype(jnp.float32)
    by_row = jnp.asarray(_cell_one_hot(row1 - row0, rows), jnp.float32)
    by_col = jnp.asarray(_cell_one_hot(col1 - col0, cols), jnp.float32)
    return (by_row.T @ events @ by_col).astype(jnp.int32).reshape(rows * cols)


def event_grid_counts(events: Events, *, roi: tuple[int, int, int, int], rows: int = 2, cols: int = 5) -> jax.Array:
    """The counts of `grid_counts` from compacted events (valid slots only, any polarity).

    Args:
        events: one `spikejax.vision.Events` stream (no batch axis).
        roi: ``(row0, row1, col0, col1)``, half-open ranges of ``y`` and ``x``;
            events outside it are ignored.
        rows, cols: grid size (static), >= 1.

    Returns:
        Counts, int32, shape ``(rows * cols,)``, index ``r * cols + c`` as in `grid_counts`.

    Raises:
        UserError: if ``roi``, ``rows`` or ``cols`` is invalid.
    """
    (row0, row1, col0, col1), rows, cols = _grid_roi(roi, rows, cols)
    x = jnp.asarray(events.x, jnp.int32)
    y = jnp.asarray(events.y, jnp.int32)
    inside = events.valid & (x >= col0) & (x < col1) & (y >= row0) & (y < row1)
    c = (cols * (x - col0)) // (col1 - col0)
    r = (rows * (y - row0)) // (row1 - row0)
    cell = jnp.where(inside, r * cols + c, 0)
    return jnp.zeros((rows * cols,), jnp.int32).at[cell].add(inside.astype(jnp.int32))


def grid_rates(counts: jax.Array, t_step, max_rate=None) -> jax.Array:
    """Poisson rates from event counts, Eq. (2) of the snake R-STDP paper: ``f = N_event / t_step``.

    A generator of rate ``f`` then fires ``N_event`` spikes on average over the
    next ``t_step`` (with `poisson_counts`; `poisson_spikes` saturates at one
    spike a step). The paper has no cap; ``max_rate`` is this project's option
    against a frame full of events driving the inputs to absurd rates.

    Args:
        counts: event counts per cell, any shape (int or float).
        t_step: the window the counts were taken over, s (20 ms in the paper), > 0.
        max_rate: optional cap, Hz, ``f = min(N / t_step, max_rate)`` (may be
            traced); ``None``: no cap.

    Returns:
        Rates, Hz, the shape of ``counts``, float: the dtype of ``counts`` and
        ``t_step`` promoted together (integer counts count as the default float).

    Raises:
        UserError: if ``t_step`` is a Python number <= 0.

    Examples:
        >>> grid_rates(jnp.array([0, 3, 10]), 0.02, max_rate=200.0).tolist()
        [0.0, 150.0, 200.0]
    """
    if isinstance(t_step, (int, float)) and not t_step > 0:
        raise UserError(f"t_step must be > 0 s, got {t_step!r}")
    counts = jnp.asarray(counts)
    dtype = jnp.result_type(counts.dtype if jnp.issubdtype(counts.dtype, jnp.floating) else float, t_step)
    f = counts.astype(dtype) / t_step
    if max_rate is not None:
        f = jnp.minimum(f, jnp.asarray(max_rate, dtype))
    return f.astype(dtype)


def antagonist_rates(alpha: jax.Array, k) -> jax.Array:
    """Rates of antagonist Poisson pairs that encode joint angles, Eq. (3) of the snake R-STDP paper.

    ``f_P = max(0, k alpha)``, ``f_N = max(0, -k alpha)``: each angle drives one
    neuron of its pair, the positive one for a positive angle, the negative one
    for a negative angle, at a rate proportional to its magnitude; the other is
    silent. The paper encodes joints 1, 3 and 5 this way.

    Args:
        alpha: joint angles, shape ``(m,)`` (units of the caller's choosing: ``k``
            is per unit of ``alpha``).
        k: gain, Hz per unit angle, > 0 (may be traced).

    Returns:
        Rates, Hz, shape ``(2 m,)``, interleaved:
        ``[f_P(alpha_0), f_N(alpha_0), f_P(alpha_1), f_N(alpha_1), ...]``.

    Examples:
        >>> antagonist_rates(jnp.array([10.0, -30.0]), 2.0).tolist()
        [20.0, 0.0, 0.0, 60.0]
    """
    scaled = k * jnp.asarray(alpha)
    zero = jnp.zeros((), scaled.dtype)
    pairs = jnp.stack([jnp.maximum(scaled, zero), jnp.maximum(-scaled, zero)], axis=-1)
    return pairs.reshape(pairs.shape[:-2] + (-1,))


def d_norm(n_right: jax.Array, n_left: jax.Array) -> jax.Array:
    """Normalised turn intention of a pair of output neurons, Eq. (4) of the snake R-STDP paper.

    ``D_norm = (N_r - N_l) / (N_r + N_l)`` in ``[-1, 1]``, positive when the right
    neuron fired more. The paper leaves the case of no spike at all undefined;
    here it is 0 (no intention to turn), without a NaN (also in gradients).

    Args:
        n_right, n_left: spike counts of the right and left neuron in the window,
            >= 0, broadcasting shapes.

    Returns:
        ``D_norm``, float (the counts' float dtype, or the default float for integer counts).

    Examples:
        >>> d_norm(jnp.array([3, 0, 0]), jnp.array([1, 2, 0])).tolist()
        [0.5, -1.0, 0.0]
    """
    n_right = jnp.asarray(n_right)
    n_left = jnp.asarray(n_left)
    dtype = jnp.result_type(n_right, n_left)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.zeros(()).dtype
    n_right = n_right.astype(dtype)
    n_left = n_left.astype(dtype)
    total = n_right + n_left
    some = total > 0
    return jnp.where(some, (n_right - n_left) / jnp.where(some, total, 1), jnp.zeros((), dtype))


def direction_step(d_prev: jax.Array, d_norm: jax.Array, eta) -> jax.Array:
    """One step of the saturating direction integrator, Eq. (5) of the snake R-STDP paper.

    ``D_t = min(1, max(-1, D_{t-1} + eta D_norm))``. It integrates rather than
    filters: a constant ``D_norm = 1`` takes ``D_t`` from 0 to 1 in ``1 / eta``
    steps, and ``eta`` sets how aggressively the direction can change (the
    paper: 0.07 for the body, 0.02 for the head).

    Args:
        d_prev: ``D_{t-1}``, in ``[-1, 1]``.
        d_norm: this step's `d_norm`.
        eta: gain, >= 0 (may be traced).

    Returns:
        ``D_t``, the broadcast shape.

    Examples:
        >>> float(direction_step(jnp.float32(0.98), jnp.float32(1.0), 0.07))
        1.0
    """
    return jnp.clip(d_prev + eta * d_norm, -1, 1)
