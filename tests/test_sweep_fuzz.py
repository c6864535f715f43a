"""Finished sweep directories damaged at random: resume gives the uninterrupted table, or one line and exit 2.

Each case copies a finished toy sweep, applies one to three random damages
(truncate, delete, garble, empty, append to, or rewrite a cell of a part,
``results.csv`` or ``metadata.json``) and resumes it through the command line's
entry point. Seeded: a failing case is reproduced by its number.
"""

from __future__ import annotations

import json
import random
import shutil

import pytest
from test_sweep import TESTS, TOY, _run, _write

from spikejax import cli
from spikejax.sweep import read_results

CASES = 60
SEED = 13


@pytest.fixture(autouse=True)
def _trials_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    path = _write(tmp, TOY.replace("chunk_size = 4", "chunk_size = 5"))
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(TESTS))
        reference = _run(path, tmp / "reference")
    return path, tmp / "reference", reference


def _garble(data: bytes, rng: random.Random) -> bytes:
    if not data:
        return bytes(rng.randrange(256) for _ in range(8))
    data = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        data[rng.randrange(len(data))] = rng.choice(b"0123456789,.-\nabcTRUEnaif \x00\xff")
    return bytes(data)


def _damage(path, rng: random.Random) -> str:
    data = path.read_bytes()
    kind = rng.choice(["truncate", "delete", "garble", "empty", "append", "cell"])
    if kind == "truncate":
        path.write_bytes(data[: rng.randrange(max(len(data), 1))])
    elif kind == "delete":
        path.unlink()
    elif kind == "garble":
        path.write_bytes(_garble(data, rng))
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "append":
        path.write_bytes(data + rng.choice([b"1,2,3\n", b"garbage", b"\n", b"{}"]))
    else:
        old, new = rng.choice(
            [
                (b"true", b"TRUE"),
                (b"false", b"0"),
                (b",1,", b",1.0,"),
                (b'"', b"'"),
                (b"e", b"E"),
                (b'"finished"', b'"finishEd"'),
                (b'"runs": [', b'"runs": [1, '),
                (b'"float32"', b'"float33"'),
                (b'"columns"', b'"column"'),
            ]
        )
        path.write_bytes(data.replace(old, new, 1))
    return f"{kind} {path.name}"


@pytest.mark.parametrize("case", range(CASES))
def test_a_damaged_directory_resumes_exactly_or_fails_in_one_line(finished, tmp_path, capsys, case):
    path, reference_dir, reference = finished
    rng = random.Random(SEED * 1000 + case)
    out = tmp_path / "out"
    shutil.copytree(reference_dir, out)
    files = sorted((out / "parts").glob("rows-*.csv")) + [out / "results.csv", out / "metadata.json"]
    damages = [_damage(file, rng) for file in rng.sample(files, rng.randint(1, 3))]

    rc = cli.main(["sweep", str(path), "--out", str(out), "--no-progress"])

    err = capsys.readouterr().err
    assert "Traceback" not in err, damages
    if rc == 0:
        assert (out / "results.csv").read_bytes() == reference, damages
        metadata = json.loads((out / "metadata.json").read_text())
        assert metadata["done_trials"] == metadata["total_trials"] == 36, damages
        assert read_results(out)["trial"].tolist() == list(range(36)), damages
    else:
        assert rc == 2, damages
        errors = [line for line in err.splitlines() if not line.startswith("warning:")]
        assert len(errors) == 1 and errors[0].startswith("spikejax sweep: error: "), (damages, err)
