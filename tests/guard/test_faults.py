"""The fault soak (``benchmarks/fault_soak.py``, shortened) on a few seeds with two busy loops beside
it: ``station sample`` against the simulated devices while faults strike every device, the RTDE
controller going away with the target channel open among them, ends by itself (exit 0) with every
target measured once, every row whole, no announced capture lost and no stored reading off the
simulated truth. Issue 33: a controller gone aborted the session (SIGABRT from ur_rtde's IO
interface) after a few targets whenever the machine was busy.

Not asserted here: the soak's ``unlogged`` count. On a loaded machine a device may take a request
only after the station has given up on it (the station says "no reply", the device's fault goes
unseen), which the benchmark's audit counts as a fault missing from the log.

The first strike is the controller going away, whatever the seed draws: drawn (one strike in ten),
a short session on a fast machine could end before one came (seed 2 in a CI run: 15 targets, no
controller gone among its faults)."""

import pytest

from benchmarks import fault_soak
from benchmarks.load_soak import busy_loops

pytestmark = pytest.mark.guard

SEEDS = (0, 1, 2)
TARGETS = 15  # 5 a line: about a minute each under the busy loops (60 take 4-5 minutes)
TIMEOUT_S = 240.0  # a session still running then is killed (and fails the test); 150 s killed
# seed 1 once in a fresh-clone CI run after 21 min of system tests (its log: recovering, not stuck),
# where the three seeds alone took 183 s together
BUSY_S = 3 * (TIMEOUT_S + 30)  # the loops end by themselves should this process die first


@pytest.fixture(scope="module")
def busy():
    """Two processes spinning on the CPU while the module's tests run (at most ``BUSY_S``)."""
    loops = busy_loops(2, BUSY_S)
    try:
        yield
    finally:
        for loop in loops:
            loop.kill()
        for loop in loops:
            loop.wait()


@pytest.mark.parametrize("seed", SEEDS)
def test_a_session_under_faults_on_a_busy_machine_measures_every_target_and_ends_by_itself(busy, seed):
    run = fault_soak.soak(TARGETS, seed, interval_s=1.0, timeout_s=TIMEOUT_S, opening=("controller gone",))
    r = run.result
    tail = "".join(line for _, line in run.log[-25:])
    assert r["exit"] == 0, f"seed {seed}: the session ended with exit {r['exit']}:\n{tail}"
    assert r["measured"] == r["targets"], (r, tail)
    assert (r["duplicates"], r["torn"], r["lost"], r["corrupt"]) == (0, 0, 0, 0), r
    assert r["faults_injected"].get("controller gone", 0) >= 1, r  # what the guard is for struck
