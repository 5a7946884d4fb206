"""Every input the station reads, mutated at random (Hypothesis, derandomised: the same cases on
every run), through the command that reads it: exit 0 or 2 (1 where a valid input reaches the
absent devices), one stderr line, no traceback, nothing written on exit 2. The cases and the
checks are in ``tests/hostile_inputs.py``; ``benchmarks/fuzz_inputs.py`` runs thousands."""

import itertools
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, note, settings
from hypothesis import strategies as st

from tests.hostile_inputs import TARGETS, make_kit, run_case

EXAMPLES = 30  # per input: 16 inputs, 480 cases
_case_ids = itertools.count()


@pytest.fixture(scope="module")
def kit(tmp_path_factory):
    return make_kit(tmp_path_factory.mktemp("kit"))


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: t.name)
@settings(
    max_examples=EXAMPLES,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_a_mutated_input_exits_0_or_2_with_one_line(kit, target, tmp_path, data):
    outcome = run_case(kit, target, tmp_path / f"case{next(_case_ids)}", data.draw)
    note(f"{target.name}: {outcome.mutation} -> exit {outcome.code}: {outcome.stderr!r}")
    assert outcome.violation is None, f"{outcome.mutation}: {outcome.violation}"


def test_the_console_script_refuses_nan_in_the_setup_with_one_line(kit, tmp_path):
    setup = tmp_path / "setup.toml"
    setup.write_text(kit.setup.read_text().replace("sigma_mm = 0.02", "sigma_mm = nan"))
    out = tmp_path / "corrected.toml"
    script = shutil.which("station", path=str(Path(sys.executable).parent))
    cmd = [script, "calibrate", kit.samples, "--robot", kit.robot, "--setup", setup, "--out", out]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr == f"station: error: {setup}: drawstring.sigma_mm: Input should be a finite number\n"
    assert not out.exists()
