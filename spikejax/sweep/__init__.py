"""Sweeps: a grid of trial parameters times a range of seeds, run chunk by chunk.

A sweep file (TOML) names a trial function, the values it holds fixed, a grid of
values and a number of seeds. ``spikejax sweep FILE --out DIR`` (or
`load_sweep` then `run_sweep`) runs every trial of the grid times the
seeds and writes one row per trial to ``DIR/results.csv``::

    [sweep]
    name = "gait_convergence"
    trial = "robots.hexapod.trial:convergence_trial"   # "module:function"
    seeds = 1000           # seeds 0 .. seeds-1 at every grid point
    base_seed = 0          # optional, default 0; 0 <= base_seed < 2**32
    chunk_size = 4096      # optional, default 1024: trials per compiled batch

    [fixed]                # optional: the same in every trial
    steps_per_gait = 100

    [grid]                 # full cartesian product of the axes, in file order
    n_gaits = [1, 2, 3]

A trial function runs one trial; the engine adds the batch with ``jax.vmap``::

    class GaitParams(NamedTuple):       # traced parameters, each a scalar
        n_gaits: int = 3
        alpha: float = 2.0

    class GaitResult(NamedTuple):       # scalar results: the table's columns
        converged: jax.Array
        iterations: jax.Array

    def convergence_trial(params: GaitParams, key: jax.Array, *,
                          steps_per_gait: int = 100) -> GaitResult: ...

The first parameter's annotation names the params NamedTuple. A ``[grid]`` key
is one of its fields (traced: one compiled program serves every value) or a
keyword-only parameter of the function (static: the engine compiles one
program per combination of the static axes' values, so they may shape the
program, e.g. the size of a network). A ``[fixed]`` key is either a field (passed as a traced
value, the same in every trial) or a keyword-only parameter of the function
(passed as a static Python value, which may shape the program). The other fields
take their defaults. Fields are passed as int32, float32 or bool arrays: by their
annotation where it is ``int``, ``float`` or ``bool``, else by the type of the
value. The function returns a NamedTuple (or a dict) of scalars. A bool result named
``nonfinite`` (`nonfinite` of the trial's state) flags a trial whose state went
NaN or infinite; the engine lists those trials at the end, with those whose
float results are NaN or infinite. Valid ranges of the params fields and of the
keyword-only parameters are declared with `spikejax.ranges.ranged` (on the
NamedTuple and on the function) and checked before anything is traced.

Rows and keys. Trials are numbered ``trial = point * seeds + seed``: ``point``
counts the grid points in the order of ``itertools.product`` over the axes in
file order (the last axis fastest), and ``seed`` runs over ``0 .. seeds-1``.
A trial's key is `trial_key`, ``jax.random.fold_in(jax.random.key(
base_seed), seed)``. It depends on the seed alone: every grid point sees the
same random numbers for the same seed (common random numbers, which make the
differences between grid points less noisy), and no trial depends on the
chunk size or on the other trials of its batch.

Example:
    >>> spec = load_sweep("sweeps/gaits.toml", seeds=10)      # doctest: +SKIP
    >>> table = read_results(run_sweep(spec, "out/gaits").parent)  # doctest: +SKIP
    >>> table["converged"].mean()                              # doctest: +SKIP

The package, one concern a module (each documents its own rules):

- `spikejax.sweep.spec`: the sweep file's schema and validation, the trial's
  signature checked against it (`load_sweep`, `SweepSpec`, `Axis`).
- `spikejax.sweep.engine`: chunks, the compiled program per static values,
  the split over devices (`spikejax.devices`), the run loop and progress
  (`run_sweep`, `trial_key`).
- `spikejax.sweep.cluster`: the chunks as Ray tasks (``run_sweep(..., ray=True)``,
  ``spikejax sweep --ray``): the cluster, the workers' compiled programs, the
  persistent compilation cache, failures; the driver alone writes.
- `spikejax.sweep.table`: the columns, their dtypes, and the text of a cell.
- `spikejax.sweep.store`: the output directory, the one place that knows the
  files: atomic writes, the lock, the parts, ``results.csv`` and
  ``metadata.json``, the rules of resuming (`read_results`).
"""

from spikejax.sweep.engine import nonfinite, run_sweep, trial_key
from spikejax.sweep.spec import Axis, SweepSpec, load_sweep
from spikejax.sweep.store import read_results

__all__ = [
    "Axis",
    "SweepSpec",
    "load_sweep",
    "nonfinite",
    "read_results",
    "run_sweep",
    "trial_key",
]
