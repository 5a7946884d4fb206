"""The simulator's announcement (``station sim serve`` -> ``station sample``): which time scale a
session runs at, a disagreeing ``--time-scale`` refused, a stale announcement ignored."""

import os

import pytest
import tomli_w

from errors import InputError
from station.acquire.runner import agree_time_scale
from station.config import station_config
from station.formats.announcement import announce, announcement_path, running_simulator, withdraw
from tests.hostile_inputs import absent_devices


@pytest.fixture
def cfg(tmp_path):
    """A station config at time scale 1 whose simulator would publish its plan in ``tmp_path``."""
    return station_config({**absent_devices(), "sim": {"plan_csv": str(tmp_path / "plan.csv")}}, "test")


def test_a_session_adopts_the_announced_time_scale_of_its_robot(cfg):
    announce(cfg.sim.plan_csv, cfg.robot.endpoint(), 20.0)
    agreed, notes = agree_time_scale(cfg, None)
    assert agreed.time_scale == 20.0 and cfg.time_scale == 1.0
    assert notes == (f"time scale 20: the simulated robot's (`station sim serve`, process {os.getpid()})",)
    assert agree_time_scale(cfg, 20.0)[0].time_scale == 20.0


def test_a_time_scale_that_disagrees_with_the_simulator_is_refused_naming_both(cfg):
    announce(cfg.sim.plan_csv, cfg.robot.endpoint(), 20.0)
    with pytest.raises(InputError) as refused:
        agree_time_scale(cfg, 1.0)
    text = str(refused.value)
    assert text.startswith(
        f"--time-scale 1: the simulated robot at {cfg.robot.endpoint()} runs at time scale 20"
    )
    assert str(announcement_path(cfg.sim.plan_csv)) in text and "give 20" in text


def test_another_robots_simulator_or_none_leaves_the_flag_or_the_config(cfg):
    announce(cfg.sim.plan_csv, "rtde 127.0.0.99:30004", 20.0)  # simulates another robot
    assert agree_time_scale(cfg, None) == (cfg, ())
    assert agree_time_scale(cfg, 5.0)[0].time_scale == 5.0
    withdraw(cfg.sim.plan_csv)
    assert not announcement_path(cfg.sim.plan_csv).exists()
    assert agree_time_scale(cfg, None)[0].time_scale == 1.0


def test_an_announcement_whose_process_is_gone_is_stale(cfg):
    path = announcement_path(cfg.sim.plan_csv)
    path.write_text(tomli_w.dumps({"robot": cfg.robot.endpoint(), "time_scale": 20.0, "pid": 999_999_999}))
    assert running_simulator(cfg.sim.plan_csv) is None
    assert agree_time_scale(cfg, None)[0].time_scale == 1.0
    withdraw(cfg.sim.plan_csv)  # not this process's: kept
    assert path.exists()


@pytest.mark.parametrize(
    "text, message",
    [
        ("robot = 'x'\ntime_scale = 'fast'\npid = 1\n", "time_scale: Input should be a valid number"),
        ("robot = 'x'\ntime_scale = 2.0\n", "pid: Field required"),
        ("robot = \n", "not valid TOML"),
    ],
)
def test_a_garbled_announcement_is_one_line_naming_it(cfg, text, message):
    path = announcement_path(cfg.sim.plan_csv)
    path.write_text(text)
    with pytest.raises(InputError, match=message) as refused:
        agree_time_scale(cfg, None)
    assert str(refused.value).startswith(str(path))


@pytest.mark.parametrize(
    "value, message", [(0.0, "greater than or equal to 0.001"), (float("nan"), "finite")]
)
def test_a_time_scale_out_of_range_names_the_flag(cfg, value, message):
    with pytest.raises(InputError, match=message) as refused:
        agree_time_scale(cfg, value)
    assert str(refused.value).startswith("--time-scale ")


def test_a_session_on_another_robot_model_than_the_simulated_one_is_refused_by_name(cfg):
    import configs
    from station.acquire.runner import agree_robot
    from station.formats.tables import load_robot

    jr680 = load_robot(configs.path("robots/hsr_jr680.toml"))
    announce(cfg.sim.plan_csv, cfg.robot.endpoint(), 1.0, "UR10")
    with pytest.raises(InputError) as refused:
        agree_robot(cfg, jr680, "jr680.toml")
    text = str(refused.value)
    assert text.startswith("jr680.toml: robot 'HSR-JR680', but the simulated robot at")
    assert "is a 'UR10'" in text and "--robot jr680.toml" in text
    agree_robot(cfg, load_robot(configs.path("robots/ur10.toml")), "ur10.toml")  # the same model: fine
    announce(cfg.sim.plan_csv, "rtde 127.0.0.99:30004", 1.0, "UR10")  # another robot's simulator
    agree_robot(cfg, jr680, "jr680.toml")
