"""The sweep engine on a Ray cluster: the local table, workers and drivers killed, trial errors, bad input.

One local cluster of 2 CPUs, started once for the module by the engine's own
`spikejax.sweep.cluster.connect` and stopped at its end; the tests that kill a
driver run it in a subprocess connected to that cluster by its address.
"""

from __future__ import annotations

import collections
import ipaddress
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from spikejax import cli
from spikejax.sweep import cluster, load_sweep, read_results, run_sweep

TESTS = Path(__file__).resolve().parent
VALUES = [float(a) for a in range(8)]
CHUNK = 2
RAY_PROCESSES = ("gcs_server", "raylet", "ray::")


def _sweep_text(sleep: float = 0.0, fail_at: float = -1.0, log: str = "", host: bool = True) -> str:
    return f"""\
[sweep]
name = "logged"
trial = "_sweep_ray_trials:logged_trial"
seeds = 1
base_seed = 3
chunk_size = {CHUNK}

[fixed]
sleep = {sleep}
fail_at = {fail_at}
log = "{log}"
host = {str(host).lower()}

[grid]
a = {VALUES}
"""


def _write(directory: Path, text: str) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "sweep.toml"
    path.write_text(text)
    return path


def _error_line(err: str) -> str:
    """The command's one error line (Ray forwards its workers' output to the driver's stderr too)."""
    lines = [line for line in err.splitlines() if line.startswith("spikejax sweep: error:")]
    assert len(lines) == 1, err
    return lines[0]


def _metadata(out: Path) -> dict:
    return json.loads((out / "metadata.json").read_text())


def _ray_children() -> list[psutil.Process]:
    found = []
    for child in psutil.Process().children(recursive=True):
        try:
            if child.name().startswith(RAY_PROCESSES) or "ray" in " ".join(child.cmdline()[:2]):
                found.append(child)
        except psutil.Error:
            pass
    return found


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A local cluster of 2 CPUs for the module; every process it started is gone afterwards."""
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(TESTS))
        # For the workers of the drivers run as subprocesses, which inherit the cluster's environment.
        patch.setenv("PYTHONPATH", os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]))
        patch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        patch.setenv("SPIKEJAX_COMPILE_CACHE", str(tmp_path_factory.mktemp("compile-cache")))
        patch.delenv("RAY_ADDRESS", raising=False)
        assert not cluster.is_connected()
        started = cluster.connect(True, num_cpus=2)
        try:
            yield started
        finally:
            cluster.disconnect()
            left = _ray_children()
            _, alive = psutil.wait_procs(left, timeout=15)
            for process in alive:  # never leave a process of the cluster behind
                process.kill()
            assert not alive, f"Ray processes left after shutdown: {[p.pid for p in alive]}"


@pytest.fixture(scope="module")
def reference(ray_cluster, tmp_path_factory) -> bytes:
    """The table of a local run (no Ray) of the sweep every test runs."""
    base = tmp_path_factory.mktemp("local")
    run_sweep(load_sweep(_write(base, _sweep_text(host=False))), base / "out", progress=False)
    return (base / "out" / "results.csv").read_bytes()


def test_the_local_cluster_listens_on_the_loopback_address_only(ray_cluster):
    assert ray_cluster.started_here and ray_cluster.address.startswith("127.0.0.1:")
    listening = []
    for process in [psutil.Process(), *_ray_children()]:
        try:
            listening += [(process.name(), c.laddr) for c in process.net_connections("inet") if c.status == "LISTEN"]
        except psutil.Error:
            pass
    assert len(listening) >= 2  # the cluster's servers at least (GCS, raylet)
    exposed = [(name, addr) for name, addr in listening if not _loopback(addr.ip)]
    assert not exposed, f"listening beyond the loopback address: {exposed}"


def _loopback(ip: str) -> bool:
    address = ipaddress.ip_address(ip)
    mapped = getattr(address, "ipv4_mapped", None)
    return (mapped or address).is_loopback


def test_ray_and_local_runs_give_the_same_table(ray_cluster, reference, tmp_path, capsys):
    path = _write(tmp_path, _sweep_text(host=False))
    out = tmp_path / "out"
    run_sweep(load_sweep(path), out, progress=True, ray=True)

    assert (out / "results.csv").read_bytes() == reference
    table = read_results(out)
    np.testing.assert_allclose(table["value"], 3.0 * table["a"] + np.sin(table["draw"]), rtol=1e-6)
    run = _metadata(out)["runs"][-1]
    assert run["devices"] == 1 and run["computed_trials"] == len(VALUES)
    assert run["ray"]["nodes"] == 1 and run["ray"]["cpus"] == 2.0 and run["ray"]["gpus"] == 0.0
    assert run["ray"]["ray_version"] == __import__("ray").__version__
    assert run["ray"]["task_devices"] == ["cpu:0"]
    # A worker wrote the chunk's program to the compilation cache (the module keeps every program there).
    assert run["compile_cache"] == os.environ["SPIKEJAX_COMPILE_CACHE"]
    assert [p for p in Path(run["compile_cache"]).iterdir() if p.name.startswith("jit_one-")]
    err = capsys.readouterr().err
    assert f"{len(VALUES) // CHUNK} chunks of {CHUNK} trials as Ray tasks on 1 node(s), 2 CPUs" in err
    assert "workers busy" in err


def test_a_worker_killed_mid_chunk_costs_that_chunk(ray_cluster, reference, tmp_path):
    log = tmp_path / "log"
    log.mkdir()
    path = _write(tmp_path, _sweep_text(sleep=0.2, log=str(log)))
    out = tmp_path / "out"
    killed: list[tuple[int, float]] = []
    firsts = {VALUES[i] for i in range(0, len(VALUES), CHUNK)}

    def kill_a_worker() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            for file in log.glob("*.txt"):
                values = [float(line) for line in file.read_text().split()]
                # The first trial of a chunk is logged: its worker is in the middle of that chunk.
                if values and values[-1] in firsts and values[-1] != VALUES[-CHUNK]:
                    os.kill(int(file.stem), signal.SIGKILL)
                    killed.append((int(file.stem), values[-1]))
                    return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_a_worker)
    killer.start()
    try:
        run_sweep(load_sweep(path), out, progress=False, ray=True)
    finally:
        killer.join()

    assert killed, "no worker was killed"
    pid, first = killed[0]
    assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    assert (out / "results.csv").read_bytes() == reference
    assert _metadata(out)["runs"][-1]["computed_trials"] == len(VALUES)
    # Every trial ran once, but the killed chunk's, which ran again.
    runs = collections.Counter(float(line) for file in log.glob("*.txt") for line in file.read_text().split())
    killed_chunk = {VALUES[VALUES.index(first) + i] for i in range(CHUNK)}
    assert set(runs) == set(VALUES)
    assert runs[first] == 2
    assert {a for a, n in runs.items() if n > 1} <= killed_chunk


def test_a_driver_killed_then_run_again_resumes(ray_cluster, reference, tmp_path):
    path = _write(tmp_path, _sweep_text(sleep=0.3))
    out = tmp_path / "out"
    command = [sys.executable, "-m", "spikejax.cli", "sweep", str(path), "--out", str(out)]
    command += ["--ray", ray_cluster.address, "--no-progress"]
    # The cluster Ray starts asks for its token (~/.ray/auth_token), sent in this mode.
    env = {**os.environ, "RAY_AUTH_MODE": "token"}
    driver = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 90
        while not list((out / "parts").glob("rows-*.csv")) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert driver.poll() is None, "the sweep ended before its driver could be killed"
    finally:
        driver.send_signal(signal.SIGKILL)
        driver.wait()
    done_before = sum(1 for _ in (out / "parts").glob("rows-*.csv")) * CHUNK
    assert 0 < done_before < len(VALUES)

    assert cli.main(["sweep", str(path), "--out", str(out), "--ray", ray_cluster.address, "--no-progress"]) == 0

    assert (out / "results.csv").read_bytes() == reference
    np.testing.assert_array_equal(read_results(out)["trial"], np.arange(len(VALUES)))
    assert _metadata(out)["runs"][-1]["computed_trials"] == len(VALUES) - done_before
    assert not list(out.rglob("*.tmp"))


def test_a_trial_that_raises_stops_the_sweep_naming_the_chunk_and_the_trial(ray_cluster, reference, tmp_path, capsys):
    path = _write(tmp_path, _sweep_text(fail_at=VALUES[-1]))
    out = tmp_path / "out"

    assert cli.main(["sweep", str(path), "--out", str(out), "--ray", "--no-progress"]) == 2

    err = _error_line(capsys.readouterr().err)
    last = len(VALUES) - 1
    assert f"the chunk of trials {last - 1}..{last} failed, at trial {last} (seed 0, a = {VALUES[-1]!r})" in err
    assert f"ValueError: a = {VALUES[-1]} is the value this trial refuses (at {TESTS / '_sweep_ray_trials.py'}:" in err
    # The chunks done before are kept, as the local run computes them.
    rows = (out / "results.csv").read_bytes().splitlines(keepends=True)
    expected = reference.splitlines(keepends=True)
    assert rows[0] == expected[0] and len(rows) >= 1 + 2 * CHUNK
    assert set(rows[1:]) <= set(expected[1 : 1 + last - 1])


@pytest.mark.parametrize(
    "flags, expected",
    [
        (["--ray", "no-port"], "--ray no-port: not an address of a Ray cluster's head (HOST:PORT, or auto)"),
        (["--ray", "127.0.0.1:1"], "--ray 127.0.0.1:1: no Ray cluster answers there"),
        (["--ray", "--cpu-devices", "2"], "--cpu-devices splits a chunk over the devices of one process"),
        (["--ray", ""], "--ray: the address is empty"),
    ],
)
def test_bad_ray_flags_are_one_line_errors(tmp_path, capsys, flags, expected):
    path = _write(tmp_path, _sweep_text())
    out = tmp_path / "out"
    sys.path.insert(0, str(TESTS))
    try:
        assert cli.main(["sweep", str(path), "--out", str(out), "--compile-cache", str(tmp_path / "c"), *flags]) == 2
    finally:
        sys.path.remove(str(TESTS))
    assert expected in _error_line(capsys.readouterr().err)
    assert not out.exists()


def test_without_ray_installed_the_error_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    monkeypatch.syspath_prepend(str(TESTS))
    out = tmp_path / "out"
    path = _write(tmp_path, _sweep_text())
    assert cli.main(["sweep", str(path), "--out", str(out), "--ray", "--compile-cache", str(tmp_path / "c")]) == 2
    err = _error_line(capsys.readouterr().err)
    assert "--ray needs Ray, which is not installed: pip install 'spikejax[ray]'" in err
    assert not out.exists()


def test_a_local_run_names_the_failing_chunk_and_trial_the_same_way(reference, tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))
    path = _write(tmp_path, _sweep_text(fail_at=VALUES[3]))
    out = tmp_path / "out"

    assert cli.main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 2

    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert f"the chunk of trials 2..3 failed, at trial 3 (seed 0, a = {VALUES[3]!r})" in err
    assert f"ValueError: a = {VALUES[3]} is the value this trial refuses (at {TESTS / '_sweep_ray_trials.py'}:" in err
    # The chunk before, finished, is kept.
    assert (out / "results.csv").read_bytes() == b"".join(reference.splitlines(keepends=True)[:3])
