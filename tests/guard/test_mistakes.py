"""The mistake checks and ``--model auto`` on simulated cells, a few seeds of the long benchmarks
(``benchmarks/mistakes.py``, ``benchmarks/terms_false_positives.py``): no false alarm on a correct
session, every flipped dial axis refused, no joint-space term kept where the world has none."""

import numpy as np
import pytest

from benchmarks import mistakes, terms_false_positives

pytestmark = pytest.mark.guard

SEEDS = 3


@pytest.mark.parametrize("n_lines, per_line", mistakes.SETTINGS)
def test_correct_sessions_raise_no_alarm_and_a_flipped_dial_is_refused(n_lines, per_line):
    found = mistakes.run(SEEDS, n_lines, per_line)
    assert (found["clean"], found["gross"], found["flip_refused"]) == (0, 0, SEEDS), found
    for key in ("dialless", "noaxis"):  # true, bound, nominal expected, nominal true, refused
        rows = np.array(found[key], float)
        written = rows[:, 4] == 0
        assert np.all(rows[written, 0] < rows[written, 3]), (key, rows)  # better than the nominal table


@pytest.mark.parametrize("setting, n_lines, per_line", terms_false_positives.SETTINGS)
def test_auto_keeps_no_term_on_cells_without_one(setting, n_lines, per_line):
    for seed in range(SEEDS):
        terms, _ = terms_false_positives.session_terms(setting, n_lines, per_line, seed)
        assert terms == [], (setting, seed)
