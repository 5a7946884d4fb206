"""Row blocks on two cores: the long per-row loops of a fit (kinematics, Jacobian rows, normal
equations; the residual map's responses and solves) split into halves, one worked by a second
thread while the caller works the other.

numpy's element-wise loops, BLAS products and batched solves release the GIL, and a block is
thousands of rows, so the two halves run at once; each block is computed as it would be alone (the
same numbers to the last digit wherever blocks write their own rows; sums of the two halves add in
another order). What it buys: docs/results/speed.md (a million rows 62-64 s -> 44-58 s wall on the
2-core machine).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable

import numpy as np

THREADS = min(2, os.cpu_count() or 1)
"""Threads that share a long array's blocks (the caller's included)."""


def halved(n: int, size: int, least: int = 32) -> int:
    """Rows per block for ``n`` rows: ``size``, or half of them where that is fewer (a short array's
    two halves on both threads), never fewer than ``least`` (below that a thread costs more than it
    saves)."""
    return max(least, min(size, -(-n // THREADS)))


def each_block(n: int, size: int, work: Callable[[int, int], tuple | None]) -> list[tuple]:
    """``work(start, stop)`` for the consecutive blocks of ``size`` of ``n`` rows (``stop`` may pass
    ``n``), the first half of the blocks in a second thread while this one works the rest.

    Returns, per half (one where there is a single block or thread), the sum term by term of what
    ``work`` returned (a tuple of arrays), in block order; an empty list where it returned None. An
    exception in either half raises here, after both have ended."""
    starts = list(range(0, n, size))
    mid = len(starts) // 2
    halves = [starts] if THREADS < 2 or mid == 0 else [starts[:mid], starts[mid:]]
    sums: list = [None] * len(halves)
    errors: list[BaseException] = []

    def run(i: int) -> None:
        try:
            for s in halves[i]:
                part = work(s, s + size)
                if part is not None:
                    sums[i] = part if sums[i] is None else tuple(map(np.add, sums[i], part))
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller's thread
            errors.append(exc)

    other = threading.Thread(target=run, args=(0,)) if len(halves) == 2 else None
    if other is not None:
        other.start()
    run(len(halves) - 1)
    if other is not None:
        other.join()
    if errors:
        raise errors[0]
    return [total for total in sums if total is not None]
