"""`station read`'s JSON: a value that is not a finite number is null, never bare NaN."""

import json
import math

from drivers.base import Reading
from station.commands.read import as_json


def test_non_finite_values_are_null_and_the_json_is_strict():
    robot = Reading("robot", {"q_deg": (1.0, math.nan, 3.0), "robot_mode": 7}, {"q_deg": "deg"}, 1.0, 2.0)
    ds = Reading("drawstring", {"length_mm": math.inf}, {"length_mm": "mm"}, 1.0, 2.0)
    text = json.dumps(as_json({"robot": robot, "drawstring": ds}), allow_nan=False)
    back = json.loads(text)
    assert back["q_deg"] == [1.0, None, 3.0] and back["length_mm"] is None and back["robot_mode"] == 7
