"""Station config: the shipped file validates and builds drivers; bad files fail with one line
naming the file, the key and the problem."""

import pytest

import configs
from drivers.dial import DialIndicator
from drivers.drawstring import AsciiDrawstring, ModbusDrawstring, RegisterMap
from errors import InputError
from station.config import load_station_config

MINIMAL = """
[robot]
kind = "rtde"
[drawstring]
kind = "modbus_rtu"
port = "/dev/ttyUSB1"
device_id = 7
[drawstring.registers]
address = 40
encoding = "float32_mm"
word_order = "little"
"""


def test_shipped_config_points_at_the_contract_addresses():
    cfg = load_station_config(configs.path("station.toml"))
    assert (cfg.robot.kind, cfg.robot.host, cfg.robot.frequency_hz) == ("rtde", "127.0.0.1", 500)
    assert (cfg.drawstring.kind, cfg.drawstring.host, cfg.drawstring.port) == (
        "modbus_tcp",
        "127.0.0.1",
        5020,
    )
    assert cfg.dial.port == "/tmp/station-sim/dial" and cfg.dial.dialect == "sylvac"
    assert isinstance(cfg.drawstring.build(), ModbusDrawstring)
    assert isinstance(cfg.dial.build(), DialIndicator)


def test_defaults_and_register_map(tmp_path):
    path = tmp_path / "station.toml"
    path.write_text(MINIMAL)
    cfg = load_station_config(path)
    assert cfg.dial is None and cfg.time_scale == 1.0 and cfg.reconnect.attempts == 4
    driver = cfg.drawstring.build()
    assert driver.registers == RegisterMap(
        address=40, encoding="float32_mm", word_order="little", device_id=7
    )
    assert driver.client.comm_params.baudrate == 115200
    assert list(cfg.devices()) == ["robot", "drawstring"]


def test_ascii_drawstring_and_mitutoyo_dial(tmp_path):
    path = tmp_path / "station.toml"
    path.write_text(
        '[robot]\nkind = "rtde"\n[drawstring]\nkind = "ascii"\nport = "/dev/ttyS0"\n'
        '[dial]\nport = "/dev/ttyS1"\ndialect = "mitutoyo"\n'
    )
    cfg = load_station_config(path)
    assert isinstance(cfg.drawstring.build(), AsciiDrawstring)
    assert cfg.dial.build().dialect.request == b"R\r"


@pytest.mark.parametrize(
    "edit, message",
    [
        (("address = 40", "address = -1"), r"drawstring\.registers\.address: Input should be greater"),
        (('encoding = "float32_mm"', 'encoding = "int16"'), r"drawstring\.registers\.encoding: "),
        (('kind = "rtde"', 'kind = "ethercat"'), r"robot: Input tag 'ethercat' found using 'kind' does not"),
        (("device_id = 7", "device_id = 7\nbaud = 9600"), r"drawstring\.baud: Extra inputs"),
        (('[robot]\nkind = "rtde"', ""), r": robot: Field required"),
        # values the session cannot work with (issue 15)
        (("address = 40", "address = 40\nscale = 0.0"), r"registers\.scale: 0: the scale must lie within"),
        (("device_id = 7", "device_id = 7\ntimeout_s = nan"), r"timeout_s: Input should be a finite"),
        (("[robot]", "time_scale = 0.0\n[robot]"), r": time_scale: Input should be greater"),
        (("/dev/ttyUSB1", "/dev/tty\\u0000"), r"drawstring\.port: String should match pattern"),
        (("[drawstring]", "[reconnect]\nfactor = 1e308\n[drawstring]"), r"reconnect\.factor: Input"),
        (
            ("[drawstring]", "[session]\ndial_range_mm = [2.0, -2.0]\n[drawstring]"),
            r"session: dial_range_mm: the low end 2 must be below the high end -2",
        ),
        (
            ('kind = "rtde"', 'kind = "ros"\ntarget_topic = "station target"'),
            r"robot\.target_topic: String should match pattern",
        ),
    ],
)
def test_bad_key_names_file_and_key(tmp_path, edit, message):
    path = tmp_path / "station.toml"
    path.write_text(MINIMAL.replace(*edit))
    with pytest.raises(InputError, match=message) as info:
        load_station_config(path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)


def test_unreadable_or_broken_file(tmp_path):
    with pytest.raises(InputError, match="missing.toml: no such file"):
        load_station_config(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text("[robot\n")
    with pytest.raises(InputError, match="bad.toml: not valid TOML"):
        load_station_config(tmp_path / "bad.toml")


def test_a_ros_robot_publishes_targets_on_its_target_topic_unless_it_is_empty(tmp_path):
    path = tmp_path / "station.toml"
    for line, topic in (("", "/station/target"), ('\ntarget_topic = "/cell_1/target"', "/cell_1/target")):
        path.write_text(MINIMAL.replace('kind = "rtde"', f'kind = "ros"{line}'))
        assert load_station_config(path).robot.build().target_topic == topic
    path.write_text(MINIMAL.replace('kind = "rtde"', 'kind = "ros"\ntarget_topic = ""'))
    robot = load_station_config(path).robot.build()
    assert robot.target_topic is None and robot.target_channel() is None
    assert robot.no_channel == "no [robot] target_topic"


def test_modbus_joint_robot_section_builds_its_driver(tmp_path):
    path = tmp_path / "station.toml"
    path.write_text(
        MINIMAL.replace(
            'kind = "rtde"',
            'kind = "modbus_tcp"\nhost = "10.0.0.5"\naddress = 200\nencoding = "float32_deg"\ndevice_id = 2',
        )
    )
    robot = load_station_config(path).robot.build()
    assert robot.name == "robot" and robot.client.comm_params.host == "10.0.0.5"
    assert (robot.registers.address, robot.registers.encoding, robot.registers.device_id) == (
        200,
        "float32_deg",
        2,
    )
