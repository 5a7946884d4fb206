"""``calib.blocks.each_block``: every block worked once, on two threads, sums and errors back."""

import threading

import numpy as np
import pytest

from calib import blocks
from calib.blocks import each_block


def test_every_block_is_worked_once_and_the_halves_sums_add_up():
    seen, threads = [], set()

    def work(s, e):
        seen.append((s, e))
        threads.add(threading.get_ident())
        return (np.arange(s, min(e, 10_001)).sum(keepdims=True),)

    halves = each_block(10_001, 1000, work)
    assert sorted(seen) == [(s, s + 1000) for s in range(0, 10_001, 1000)]
    assert sum(h[0][0] for h in halves) == np.arange(10_001).sum()
    assert len(halves) == 2 and len(threads) == 2


def test_a_single_block_is_worked_in_the_callers_thread():
    threads = []

    def work(s, e):
        threads.append(threading.get_ident())
        return (np.ones(1),)

    assert each_block(5, 1000, work) == [(np.ones(1),)]
    assert threads == [threading.get_ident()]


def test_work_that_returns_nothing_gives_no_sums():
    out = np.zeros(9_000)

    def work(s, e):
        out[s:e] = np.arange(s, min(e, out.size))

    assert each_block(out.size, 1000, work) == []
    assert np.array_equal(out, np.arange(out.size))


def test_an_error_in_the_second_thread_raises_in_the_caller():
    def work(s, e):
        if s == 0:  # the first half's: worked by the second thread
            raise ValueError("block 0")

    with pytest.raises(ValueError, match="block 0"):
        each_block(4000, 1000, work)


def test_a_short_array_is_halved_for_both_threads_a_long_one_keeps_its_blocks(monkeypatch):
    monkeypatch.setattr(blocks, "THREADS", 2)
    assert blocks.halved(210, 256) == 105  # a 210-row session's posterior: two halves
    assert blocks.halved(100_000, 256) == 256
    assert blocks.halved(20, 256) == 32  # too short to be worth a thread: one block
    monkeypatch.setattr(blocks, "THREADS", 1)
    assert blocks.halved(210, 256) == 210
