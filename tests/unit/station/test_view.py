"""What the station draws and logs, as data: the calibration plot's bars per placement (rows on no
line kept apart from line 1) and the session log's warning level."""

import numpy as np
import pytest

from station.view.live import log_level
from station.view.plots import rms_per_placement


def test_rows_on_no_line_get_their_own_bar_not_line_1s():
    errors = np.array([3.0, 4.0, 1.0, 1.0, 0.5])
    placement = np.array([-1, -1, 1, 1, 0])
    ids, rms = rms_per_placement(errors, placement)
    assert ids.tolist() == [-1, 0, 1]
    assert rms == pytest.approx([np.sqrt(12.5), 0.5, 1.0])


@pytest.mark.parametrize(
    "text, warn",
    [
        ("suspended: drawstring not answering", True),
        ("drawstring: bad CRC in reply 01 03; retrying", True),
        ("capture at target 4 rejected: the robot left before the capture finished, so it will be", True),
        ("sample 12: reading +0.300 mm off the running calibration: check the cable", True),
        ("running calibration: refit failed: ValueError", True),
        ("running calibration: the model is determined by 26 samples", False),
        ("line 0 saturated at 0.2 mm predicted: its last 10 samples improved it only 2 %", False),
    ],
)
def test_a_log_line_is_a_warning_when_it_reports_a_fault(text, warn):
    assert log_level(text).value == ("WARN" if warn else "INFO")
