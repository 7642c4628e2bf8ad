"""experiments.scheduling: the threads that run an experiment's phases."""

from __future__ import annotations

import threading
import time

import pytest

from experiments import scheduling


def test_workers_raise_the_first_failure_while_others_still_run():
    """A phase that fails stops the experiment at once, not when its turn comes; closing the
    workers sets the event that running phases check."""
    release = threading.Event()
    workers = scheduling.Workers(2)
    try:
        slow = workers.submit(release.wait, 30)

        def fail():
            raise FloatingPointError("diverged")

        failing = workers.submit(fail)
        start = time.perf_counter()
        with pytest.raises(FloatingPointError, match="diverged"):
            workers.results({"slow": slow, "failing": failing})
        assert time.perf_counter() - start < 10 and not slow.done()
        assert not workers.cancel.is_set()
    finally:
        release.set()
        workers.close()
    assert workers.cancel.is_set() and slow.result() is True
    with pytest.raises(RuntimeError):  # closed: no new phase starts
        workers.submit(print)
