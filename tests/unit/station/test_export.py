"""`station export` as a user runs it: URDF read back by an independent reader (pytransform3d),
Universal Robots' kinematics file composed back to the table's flange and the nominal UR10 file
reproduced, the D-H CSV, and bad input."""

import csv

import numpy as np
import pytest
import tomli_w
import tomllib
import yaml
from pytransform3d.urdf import UrdfTransformManager

import configs
from calib.frames import matrix_from_rpy, rot_z
from calib.kinematics import base_from_frames
from station.cli import main
from station.formats.tables import load_robot

UR_ENTRIES = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
# Universal Robots' ur_description, config/ur10/default_kinematics.yaml (x y z [m], roll pitch yaw [rad])
UR10_DEFAULT = {
    "shoulder": (0, 0, 0.1273, 0, 0, 0),
    "upper_arm": (0, 0, 0, 1.570796327, 0, 0),
    "forearm": (-0.612, 0, 0, 0, 0, 0),
    "wrist_1": (-0.5723, 0, 0.163941, 0, 0, 0),
    "wrist_2": (0, -0.1157, -2.373046667922381e-11, 1.570796327, 0, 0),
    "wrist_3": (0, 0.0922, -1.891053610911353e-11, 1.570796326589793, 3.141592653589793, 3.141592653589793),
}


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _robot_file(path, name, error=None, **extra):
    """A robot TOML: the shipped ``name`` table plus ``error`` (6, 4: theta_deg, d, a, alpha_deg)."""
    data = tomllib.loads(configs.path(f"robots/{name}.toml").read_text())
    for j, joint in enumerate(data["joints"]):
        for k, key in enumerate(("theta_deg", "d_mm", "a_mm", "alpha_deg")):
            joint[key] += 0.0 if error is None else float(error[j, k])
    data.update(extra)
    path.write_text(tomli_w.dumps(data))
    return path


def _flange(path, q):
    robot = load_robot(path).model()
    return base_from_frames(robot.dh, q)[:, 6], robot


def _compose(entries, q):
    """Base-from-wrist_3 poses of a kinematics file: origin then Rz(q) per joint."""
    out = []
    for qi in q:
        pose = np.eye(4)
        for name, angle in zip(UR_ENTRIES, qi, strict=True):
            e = entries[name]
            origin = np.eye(4)
            origin[:3, :3] = matrix_from_rpy((e["roll"], e["pitch"], e["yaw"]))
            origin[:3, 3] = 1000.0 * np.array([e["x"], e["y"], e["z"]])
            pose = pose @ origin @ rot_z(angle)
        out.append(pose)
    return np.array(out)


def _assert_same_poses(a, b):
    np.testing.assert_allclose(a[:, :3, 3], b[:, :3, 3], atol=1e-3)  # 1 um
    np.testing.assert_allclose(a[:, :3, :3], b[:, :3, :3], atol=1e-6)  # rad


@pytest.fixture
def corrected_jr680(tmp_path, rng):
    """A 'calibrated' JR680: every parameter off (J6 a and alpha too), and a tool."""
    error = rng.normal(0, [0.15, 0.75, 0.75, 0.15], (6, 4))
    return _robot_file(tmp_path / "corrected.toml", "hsr_jr680", error, tool_mm=[12.0, -4.0, 150.0])


def test_urdf_fk_equals_the_table_through_an_independent_reader(corrected_jr680, tmp_path, capsys, rng):
    out = tmp_path / "robot.urdf"
    code, text, _ = _cli(capsys, "export", corrected_jr680, "--format", "urdf", "--out", out)
    assert code == 0 and f"wrote {out}" in text
    manager = UrdfTransformManager()
    manager.load_urdf(out.read_text())
    flange, robot = _flange(corrected_jr680, np.zeros((1, 6)))
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (1000, 6))
    poses = []
    for qi in q:
        for j in range(6):
            manager.set_joint(f"joint_{j + 1}", qi[j])
        poses.append(manager.get_transform("tcp", "base_link"))
    poses = np.array(poses)
    poses[:, :3, 3] *= 1000.0
    tcp, _ = _flange(corrected_jr680, q)
    tcp[:, :3, 3] += tcp[:, :3, :3] @ robot.tool
    _assert_same_poses(poses, tcp)
    # limits from the table, in radians
    np.testing.assert_allclose(manager.get_joint_limits("joint_2"), robot.limits[1], atol=1e-9)


def test_ur_yaml_composes_to_the_flange(tmp_path, capsys, rng):
    """A calibrated UR10 (J6 a and alpha at nominal, as the calibration holds alpha6): origin then a
    turn by the reading, joint by joint, gives the table's flange."""
    error = rng.normal(0, [0.15, 0.75, 0.75, 0.15], (6, 4))
    error[5, 2:] = 0.0
    table = _robot_file(tmp_path / "ur.toml", "ur10", error)
    out = tmp_path / "kinematics.yaml"
    code, text, _ = _cli(capsys, "export", table, "--format", "ur-yaml", "--out", out, "--hash", "calib_42")
    assert code == 0
    assert "factory model" in text and "station compensate" in text  # Cartesian moves stay uncorrected
    kinematics = yaml.safe_load(out.read_text())["kinematics"]
    assert list(kinematics) == [*UR_ENTRIES, "hash"] and kinematics["hash"] == "calib_42"
    q = rng.uniform(-2 * np.pi, 2 * np.pi, (1000, 6))
    _assert_same_poses(_compose(kinematics, q), _flange(table, q)[0])


def test_ur_yaml_names_what_it_cannot_hold(corrected_jr680, tmp_path, capsys, rng):
    """J6 a and alpha lie after the last joint: the note gives them, and with them the flange."""
    out = tmp_path / "kinematics.yaml"
    code, text, _ = _cli(capsys, "export", corrected_jr680, "--format", "ur-yaml", "--out", out)
    assert code == 0
    robot = load_robot(corrected_jr680).model()
    assert f"{robot.dh[5, 2]:.4f} mm along x of wrist_3_link" in text
    assert "tool_mm" in text and "hash 'unknown'" in text
    assert "warning: HSR-JR680 is not a Universal Robots arm by its name: ur-yaml is" in text
    q = rng.uniform(-np.pi, np.pi, (200, 6))
    remainder = np.eye(4)
    remainder[0, 3] = robot.dh[5, 2]
    c, s = np.cos(robot.dh[5, 3]), np.sin(robot.dh[5, 3])
    remainder[1:3, 1:3] = [[c, -s], [s, c]]
    kinematics = yaml.safe_load(out.read_text())["kinematics"]
    _assert_same_poses(_compose(kinematics, q) @ remainder, _flange(corrected_jr680, q)[0])


def test_nominal_ur10_gives_universal_robots_default_file(tmp_path, capsys, rng):
    out = tmp_path / "ur10.yaml"
    ur10 = configs.path("robots/ur10.toml")
    code, text, _ = _cli(capsys, "export", ur10, "--format", "ur-yaml", "--out", out)
    assert code == 0 and "warning" not in text  # a UR by its name
    ours = yaml.safe_load(out.read_text())["kinematics"]
    theirs = {
        n: dict(zip(("x", "y", "z", "roll", "pitch", "yaw"), v, strict=True)) for n, v in UR10_DEFAULT.items()
    }
    for name in UR_ENTRIES:
        for key in ("x", "y", "z"):
            assert ours[name][key] == pytest.approx(theirs[name][key], abs=1e-9), (name, key)
        angles = [ours[name][k] for k in ("roll", "pitch", "yaw")]
        expected = [theirs[name][k] for k in ("roll", "pitch", "yaw")]
        if name == "wrist_3":  # theirs (pi/2, pi, pi), ours (-pi/2, 0, 0): the same rotation
            np.testing.assert_allclose(matrix_from_rpy(angles), matrix_from_rpy(expected), atol=1e-9)
        else:
            np.testing.assert_allclose(angles, expected, atol=1e-9)
    q = rng.uniform(-2 * np.pi, 2 * np.pi, (1000, 6))
    _assert_same_poses(_compose(ours, q), _compose(theirs, q))
    _assert_same_poses(_compose(theirs, q), _flange(configs.path("robots/ur10.toml"), q)[0])


def test_hash_from_the_table_the_robot_or_the_flag(tmp_path, capsys):
    nominal = _robot_file(tmp_path / "nominal.toml", "ur10", controller_hash="calib_111")
    table = _robot_file(tmp_path / "table.toml", "ur10")
    out = tmp_path / "k.yaml"

    def written(*extra):
        code, text, _ = _cli(capsys, "export", table, "--format", "ur-yaml", "--out", out, *extra)
        assert code == 0
        return yaml.safe_load(out.read_text())["kinematics"]["hash"], text

    assert written()[0] == "unknown"
    assert written("--robot", nominal)[0] == "calib_111"
    assert written("--robot", nominal, "--hash", "calib_222")[0] == "calib_222"
    _robot_file(table, "ur10", controller_hash="calib_333")
    hash_, text = written()
    assert hash_ == "calib_333" and "hash calib_333" in text


def test_dh_csv_with_deltas(corrected_jr680, tmp_path, capsys):
    nominal = configs.path("robots/hsr_jr680.toml")
    out = tmp_path / "dh.csv"
    assert (
        _cli(capsys, "export", corrected_jr680, "--format", "dh-csv", "--out", out, "--robot", nominal)[0]
        == 0
    )
    rows = list(csv.DictReader(out.open()))
    assert [r["joint"] for r in rows] == ["1", "2", "3", "4", "5", "6"]
    table, nom = load_robot(corrected_jr680).table_deg(), load_robot(nominal).table_deg()
    for j, row in enumerate(rows):
        for k, key in enumerate(("theta_deg", "d_mm", "a_mm", "alpha_deg")):
            assert float(row[key]) == pytest.approx(table[j, k], abs=1e-6)
            assert float(row[f"delta_{key}"]) == pytest.approx(table[j, k] - nom[j, k], abs=1e-6)
    assert _cli(capsys, "export", corrected_jr680, "--format", "dh-csv", "--out", out)[0] == 0
    assert out.read_text().splitlines()[0] == "joint,alpha_deg,a_mm,d_mm,theta_deg"


def test_bad_input_exits_2_with_one_line_and_writes_nothing(corrected_jr680, tmp_path, capsys):
    out = tmp_path / "out.urdf"
    five = tmp_path / "five.toml"
    data = tomllib.loads(corrected_jr680.read_text())
    data["joints"] = data["joints"][:5]
    five.write_text(tomli_w.dumps(data))
    ur10 = configs.path("robots/ur10.toml")
    cases = [
        (("export", five, "--format", "urdf", "--out", out), f"{five}: joints: expected 6 joints, got 5"),
        (
            ("export", corrected_jr680, "--format", "urdf", "--out", tmp_path / "no" / "x.urdf"),
            "does not exist",
        ),
        (("export", corrected_jr680, "--format", "urdf", "--out", out, "--hash", "c"), "--hash"),
        (
            ("export", corrected_jr680, "--format", "dh-csv", "--out", out, "--robot", ur10),
            "not a calibration",
        ),
        (("export", tmp_path / "missing.toml", "--format", "urdf", "--out", out), "no such file"),
    ]
    for argv, message in cases:
        code, _, err = _cli(capsys, *argv)
        assert code == 2, argv
        assert len(err.strip().splitlines()) == 1 and message in err, err
        assert not out.exists()


@pytest.mark.parametrize("fmt", ["urdf", "ur-yaml", "dh-csv"])
def test_a_table_with_terms_exports_its_geometry_and_says_what_is_left_out(tmp_path, capsys, fmt):
    """No target format holds a compliance or a harmonic: the file is the same as without them and
    the output names them."""
    data = tomllib.loads(configs.path("robots/ur10.toml").read_text())
    plain = tmp_path / "plain.toml"
    plain.write_text(tomli_w.dumps(data))
    data["joints"][1].update(compliance_urad_per_Nm=12.3, sin1_deg=0.02)
    with_terms = tmp_path / "terms.toml"
    with_terms.write_text(tomli_w.dumps(data))
    texts = []
    for src in (plain, with_terms):
        out = tmp_path / f"{src.stem}.{fmt}"
        hash_ = ["--hash", "calib_1"] if fmt == "ur-yaml" else []
        code, text, _ = _cli(capsys, "export", src, "--format", fmt, "--out", out, *hash_)
        assert code == 0
        texts.append((text, out.read_text().replace(src.name, "")))
    assert "left out" not in texts[0][0]
    left_out = "the table's joint-space terms (J2.compliance_urad_per_Nm, J2.sin1_deg) are left out"
    assert f"note: {fmt} holds the geometry only: {left_out}" in texts[1][0]
    assert texts[0][1] == texts[1][1]
