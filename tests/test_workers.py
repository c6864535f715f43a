"""`spikejax.workers`: the seeds' shares and the pinned pool."""

import pytest

from spikejax import workers
from spikejax.errors import UserError


def _core():
    import os
    import time

    time.sleep(0.2)  # so that both processes take tasks
    return os.getpid(), sorted(os.sched_getaffinity(0))


@pytest.mark.parametrize("n, k", [(64, 2), (5, 2), (3, 4), (7, 3), (1, 1)])
def test_shares_cover_the_seeds_in_order_in_near_equal_contiguous_slices(n, k):
    shares = workers.shares(n, k)
    assert shares[0][0] == 0 and shares[-1][1] == n and len(shares) == min(n, k)
    assert all(a[1] == b[0] for a, b in zip(shares, shares[1:]))
    sizes = [b - a for a, b in shares]
    assert min(sizes) >= 1 and max(sizes) - min(sizes) <= 1


def test_workers_default_to_one_a_core_and_refuse_nonsense():
    assert workers.workers_for_run() == len(workers.cores())
    assert workers.workers_for_run(3) == 3
    for bad in (0, -1, 1.5, True):
        with pytest.raises(UserError, match="workers must be"):
            workers.workers_for_run(bad)


def test_each_worker_is_pinned_to_one_core_of_its_own():
    with workers.pool(2) as pool:
        seen = dict(f.result() for f in [pool.submit(_core) for _ in range(6)])
    cores = workers.cores()
    assert all(len(c) == 1 and c[0] in cores for c in seen.values())
    if len(cores) > 1 and len(seen) == 2:
        assert len({c[0] for c in seen.values()}) == 2
