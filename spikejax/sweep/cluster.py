"""A sweep's chunks as Ray tasks: one driver writes, any number of workers compute.

``run_sweep(spec, out, ray=True)`` (``spikejax sweep FILE --out DIR --ray
[ADDRESS]``) connects to a Ray cluster and runs every missing chunk as one Ray
task. A task runs in a worker process: it compiles the trial, ``jax.vmap``-ed
over the chunk's padded length on one device, once per worker process and
static values (the program is kept for the worker's next chunks), and returns
the chunk's results. The driver alone writes: each finished chunk becomes a
part (`spikejax.sweep.store`), so the files, the resume rules and the table
are those of a local run, and the same seed gives the same row (a chunk is the
same program on the same one device as a local run's, so a local run and a
Ray run give the same table byte for byte).

Which cluster. ``ray=<address>`` connects to that cluster (``host:port`` of
its head, or ``auto`` for the one started on this machine by ``ray start``);
``ray=True`` takes ``$RAY_ADDRESS`` and, without it, starts a cluster of its
own on this machine, stopped at the end of the run. That local cluster binds
every port to the loopback address, with the dashboard (which carries Ray's
job-submission server) off: a Ray cluster runs whatever code is submitted to
it, and its endpoints reachable from a network would be a remote shell for
anyone on it. Connecting to a cluster elsewhere is the user's explicit choice.

Failures. A worker killed in the middle of a chunk (SIGKILL, the memory
monitor, a node lost) costs that chunk: Ray runs the task again
(``_TASK_RETRIES`` times). A driver killed at any moment leaves whole parts
behind; the same command resumes from them. A trial that raises (in a host
callback, say) stops the sweep with one line that names the chunk and the
trial: the worker runs halves of the chunk again to find the first trial that
raises. The chunks already finished are kept.

Compilation. Every worker compiles the same programs; JAX's persistent
compilation cache (``compile_cache``, a directory on storage the workers
share, `default_compile_cache` by default) lets the first compilation of a
program serve every worker and every later run. JAX writes only programs that
took longer than ``jax_persistent_cache_min_compile_time_secs`` (1 s) to
compile and that call no host callback; it saves the XLA compilation, not the
tracing and lowering before it. Only trusted users should write in that directory: JAX loads what it
finds there as machine code.

The code. Each worker imports the trial's module: on a cluster started here
the workers see the driver's ``sys.path``; on another cluster the trial's
package (and spikejax) must be installed on every node, or the module sit in
the directory the driver runs in (Ray puts it on the workers' path).
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import socket
import sys
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from spikejax.errors import UserError

__all__ = [
    "Cluster",
    "check_compile_cache",
    "connect",
    "default_compile_cache",
    "disconnect",
    "is_connected",
    "run_chunks",
    "use_compile_cache",
]

INSTALL_HINT = "pip install 'spikejax[ray]'"
_TASK_RETRIES = 3
_CONNECT_TIMEOUT_S = 5.0
# Ray binds to the loopback address only where it thinks clusters are unsupported (its check for
# macOS and Windows); this variable, seen before Ray is imported, makes it think so.
_LOOPBACK_ONLY = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


class Cluster(NamedTuple):
    """The Ray cluster a run uses, as ``metadata.json`` records it.

    Attributes:
        address: the head's ``host:port``.
        started_here: whether this process started it (and stops it at the end).
        nodes: the nodes alive when the run began.
        cpus: their CPUs, as Ray counts them.
        gpus: their GPUs.
        ray_version: Ray's version on the driver.
    """

    address: str
    started_here: bool
    nodes: int
    cpus: float
    gpus: float
    ray_version: str

    def record(self) -> dict[str, Any]:
        """The record of ``metadata.json`` (a run's ``ray``)."""
        return dict(self._asdict())


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise UserError(f"--ray needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


def default_compile_cache() -> Path:
    """The persistent compilation cache a Ray run uses without ``--compile-cache``.

    ``$SPIKEJAX_COMPILE_CACHE`` if set, else ``spikejax/jax-compile`` in
    ``$XDG_CACHE_HOME`` (``~/.cache``). On a cluster of several machines, put it
    on storage they share so that a program is compiled once per cluster.
    """
    if os.environ.get("SPIKEJAX_COMPILE_CACHE"):
        return Path(os.environ["SPIKEJAX_COMPILE_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "spikejax" / "jax-compile"


def check_compile_cache(directory: str | os.PathLike[str]) -> Path:
    """``directory`` made absolute and created; a UserError if it cannot be written."""
    path = Path(directory).expanduser().resolve()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UserError(f"--compile-cache {directory}: cannot create it: {err.strerror or err}") from None
    if not path.is_dir() or not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"--compile-cache {directory}: not a directory this user may write in")
    return path


def use_compile_cache(directory: str | os.PathLike[str]) -> None:
    """Makes JAX in this process read and write compiled programs in ``directory``.

    Takes effect for the programs compiled afterwards (JAX reads the directory
    when it first compiles; the cache is reset if it had started elsewhere).
    """
    from jax._src import compilation_cache

    path = str(directory)
    if jax.config.jax_compilation_cache_dir != path:
        jax.config.update("jax_compilation_cache_dir", path)
        compilation_cache.reset_cache()


def _check_address(address: str) -> None:
    """A UserError unless a Ray head answers at ``host:port`` (``auto`` is left to Ray)."""
    if address == "auto":
        return
    host, sep, port = address.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UserError(f"--ray {address}: not an address of a Ray cluster's head (HOST:PORT, or auto)")
    try:
        with socket.create_connection((host, int(port)), timeout=_CONNECT_TIMEOUT_S):
            pass
    except OSError as err:
        raise UserError(
            f"--ray {address}: no Ray cluster answers there ({err.strerror or err}); start one with "
            "`ray start --head` or leave out the address to run on a cluster of this machine"
        ) from None


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@contextlib.contextmanager
def _loopback_only(ray: Any) -> Iterator[None]:
    from ray._private import ray_constants

    saved_env, saved_flag = os.environ.get(_LOOPBACK_ONLY), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[_LOOPBACK_ONLY] = "0"  # for the processes Ray starts
    ray_constants.ENABLE_RAY_CLUSTER = False  # for this one, where Ray read it at import
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = saved_flag
        if saved_env is None:
            os.environ.pop(_LOOPBACK_ONLY, None)
        else:
            os.environ[_LOOPBACK_ONLY] = saved_env


def _driver_path() -> str:
    return os.pathsep.join(dict.fromkeys(os.path.abspath(p) for p in sys.path if p and os.path.isdir(p)))


def connect(address: str | bool | None = True, *, num_cpus: int | None = None) -> Cluster:
    """Connects this process to a Ray cluster, or starts one on this machine.

    Args:
        address: ``host:port`` of a running cluster's head, or ``auto``; True or
            None: ``$RAY_ADDRESS``, else a new cluster on this machine bound to
            the loopback address, with its dashboard and job server off. A
            process already connected keeps its connection.
        num_cpus: the CPUs of a cluster started here (default: all of them).

    Returns:
        The cluster.

    Raises:
        UserError: Ray is not installed, the address is malformed or nothing
            answers there, or Ray fails to start or connect (its first line).
    """
    ray = _import_ray()
    if isinstance(address, bool) or address is None:
        address = os.environ.get("RAY_ADDRESS") or None
    started_here = False
    if address:
        _check_address(address)
    if not ray.is_initialized():
        stack = contextlib.ExitStack()
        options: dict[str, Any] = {
            "configure_logging": True,
            "logging_level": "warning",
            "log_to_driver": True,
        }
        try:
            stack.enter_context(warnings.catch_warnings())
            # Ray starts its processes by fork and exec, which JAX's fork warning does not tell apart.
            warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
            if address:
                # A cluster bound to the loopback address (one started here by another run) is
                # reached from the loopback address: Ray would otherwise swap it for the host's.
                loopback = address != "auto" and _is_loopback(address.rpartition(":")[0].strip("[]"))
                if loopback:
                    stack.enter_context(_loopback_only(ray))
                ray.init(address=address, **options)
            else:
                with _loopback_only(ray):
                    ray.init(
                        address="local",
                        num_cpus=num_cpus,
                        include_dashboard=False,
                        _node_ip_address="127.0.0.1",
                        runtime_env={"env_vars": {"PYTHONPATH": _driver_path()}},
                        **options,
                    )
                started_here = True
        except UserError:
            raise
        except Exception as err:  # noqa: BLE001 - Ray's own failures (ConnectionError, RuntimeError, ...)
            with contextlib.suppress(Exception):
                ray.shutdown()
            where = f"at {address}" if address else "on this machine"
            hint = (
                " (a cluster with token authentication is reached with RAY_AUTH_MODE=token and its token in "
                "RAY_AUTH_TOKEN or ~/.ray/auth_token)"
                if address
                else ""
            )
            raise UserError(
                f"--ray: cannot use a Ray cluster {where}: {type(err).__name__}: {_first_line(err)}{hint}"
            ) from None
        finally:
            stack.close()
    gcs = ray.get_runtime_context().gcs_address
    if started_here and not gcs.startswith("127.0.0.1:"):
        ray.shutdown()
        raise UserError(f"--ray: the local Ray cluster bound to {gcs}, not to the loopback address; stopped it")
    nodes = [node for node in ray.nodes() if node.get("Alive")]
    resources = ray.cluster_resources()
    return Cluster(
        address=gcs,
        started_here=started_here,
        nodes=len(nodes),
        cpus=float(resources.get("CPU", 0.0)),
        gpus=float(resources.get("GPU", 0.0)),
        ray_version=ray.__version__,
    )


def is_connected() -> bool:
    """Whether this process is connected to a Ray cluster (False where Ray was never imported)."""
    ray = sys.modules.get("ray")
    return bool(ray is not None and ray.is_initialized())


def disconnect() -> None:
    """Disconnects this process from its Ray cluster, and stops the cluster if it started it."""
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        ray.shutdown()


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


# ----------------------------------------------------------------------------- worker side

# The programs this worker process compiled: (fingerprint, static values, length, columns) -> program.
_PROGRAMS: dict[tuple[Any, ...], Any] = {}


class _Done(NamedTuple):
    results: list[np.ndarray]
    compile_seconds: float
    device: str


class _Failed(NamedTuple):
    trial: int | None
    message: str


def _compute_chunk(
    spec: Any, results: list[Any], start: int, end: int, length: int, cache_dir: str | None
) -> _Done | _Failed:
    """A Ray task: the trials ``start .. end-1`` of ``spec``, padded to ``length``, on one device."""
    from spikejax.sweep import engine

    if cache_dir:
        use_compile_cache(cache_dir)
    static_values = engine._static_values(spec, start)
    key = (spec.fingerprint, tuple(static_values.items()), length, tuple(results))
    compile_seconds = 0.0
    device = jax.devices()[0]
    if key not in _PROGRAMS:
        began = time.perf_counter()
        try:
            batched = engine._batched_trial(spec, results, static_values, [device])
            _PROGRAMS[key] = batched.compile(*engine._chunk_inputs(spec, 0, 1, length))
        except Exception as err:  # noqa: BLE001 - the trial's, for these static values
            return _Failed(None, engine.error_text(err))
        compile_seconds = time.perf_counter() - began
    program = _PROGRAMS[key]

    def run(first: int, last: int) -> list[np.ndarray]:
        outputs = program(*engine._chunk_inputs(spec, first, last, length))
        return [np.asarray(values)[: last - first] for values in outputs]

    with engine.quiet_callback_errors():
        try:
            return _Done(run(start, end), compile_seconds, str(device))
        except Exception as err:  # noqa: BLE001 - the trial raised while it ran
            message = engine.error_text(err)
        return _Failed(engine.first_failing(run, start, end), message)


# ----------------------------------------------------------------------------- driver side


def _task_slots(cluster: Cluster) -> tuple[int, float]:
    """How many chunks run at once, and the GPUs each task asks for."""
    if cluster.gpus >= 1:
        return int(cluster.gpus), 1.0
    return max(1, int(cluster.cpus)), 0.0


def run_chunks(
    spec: Any,
    store: Any,
    results: list[Any],
    chunks: list[tuple[int, int]],
    length: int,
    bar: Any,
    cluster: Cluster,
    cache_dir: Path | None,
    write: Any,
) -> None:
    """Runs ``chunks`` as Ray tasks and writes each with ``write(start, end, results)`` as it finishes.

    At most twice as many tasks as the cluster has slots (CPUs, or GPUs where it
    has some, one a task) are in flight, so that a worker finds its next chunk
    waiting; the progress bar shows how many workers are busy.

    Raises:
        UserError: a trial raised (the chunk and the trial named), or a chunk's
            worker died more often than Ray retries, or a worker cannot import the
            trial. The chunks finished before are written.
    """
    from spikejax.sweep import engine

    ray = _import_ray()
    slots, gpus = _task_slots(cluster)
    remote = ray.remote(
        num_cpus=0 if gpus else 1,
        num_gpus=gpus,
        max_retries=_TASK_RETRIES,
        retry_exceptions=False,
        max_calls=0,  # keep the worker (and its compiled programs) after a GPU task too
    )(_compute_chunk)
    spec_ref = ray.put(spec)
    cache = str(cache_dir) if cache_dir is not None else None
    pending = iter(chunks)
    in_flight: dict[Any, tuple[int, int]] = {}
    devices: set[str] = set()
    last = [0, 0]  # the range of the chunk collected last
    store.run["ray"]["task_devices"] = []

    def submit() -> None:
        for start, end in pending:
            in_flight[remote.remote(spec_ref, results, start, end, length, cache)] = (start, end)
            if len(in_flight) >= 2 * slots:
                return

    def collect(ref: Any) -> _Failed | None:
        start, end = in_flight.pop(ref)
        last[:] = [start, end]
        try:
            outcome = ray.get(ref)
        except ray.exceptions.RayTaskError as err:
            cause = getattr(err, "cause", None) or err
            hint = (
                " (install the trial's package and spikejax on every node, or run from the directory that holds "
                "the trial's module)"
                if "No module named" in str(cause)  # the spec could not be unpickled there
                else ""
            )
            return _Failed(None, f"a Ray worker could not run it: {type(cause).__name__}: {_first_line(cause)}{hint}")
        except ray.exceptions.RayError as err:
            return _Failed(
                None,
                f"its Ray worker died {_TASK_RETRIES + 1} times ({type(err).__name__}: {_first_line(err)}); "
                "a trial that runs out of memory kills its worker",
            )
        if isinstance(outcome, _Failed):
            return outcome
        write(start, end, outcome.results)
        store.add_compile_seconds(outcome.compile_seconds)
        if outcome.device not in devices:
            devices.add(outcome.device)
            store.run["ray"]["task_devices"] = sorted(devices)
        return None

    def busy() -> None:
        bar.set_postfix_str(f"workers busy {min(len(in_flight), slots)}/{slots}", refresh=False)

    try:
        submit()
        busy()
        while in_flight:
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            failure = collect(ready[0])
            if failure is not None:
                start, end = last
                _stop(ray, in_flight, collect)
                raise engine.chunk_failed(spec, start, end, failure.message, failure.trial)
            submit()
            busy()
    except BaseException:
        for ref in in_flight:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        raise


def _stop(ray: Any, in_flight: dict[Any, tuple[int, int]], collect: Any) -> None:
    """After a failure: keep the chunks finished meanwhile, cancel the others."""
    if not in_flight:
        return
    ready, _ = ray.wait(list(in_flight), num_returns=len(in_flight), timeout=0)
    for ref in ready:
        collect(ref)
    for ref in list(in_flight):
        with contextlib.suppress(Exception):
            ray.cancel(ref, force=True)
        in_flight.pop(ref)
