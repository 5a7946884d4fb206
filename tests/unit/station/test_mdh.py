"""Robot files in Craig's modified D-H (``convention = "mdh"``): the chain computes as Craig writes
it, one robot written both ways gives the same TCP and calibrates to the same TCP, the corrected
table is written (and read back) in the file's own convention, its true workspace error within
the report's 95 % bound."""

import json

import numpy as np
import pytest
import tomli_w
from scipy.spatial.transform import Rotation

import configs
from calib.conventions import com_to_mdh, dh_from_mdh, dh_name, mdh_from_dh, mdh_name
from calib.kinematics import base_from_frames, tcp_position
from calib.metrics import aligned_errors
from calib.params import DH_KEYS, DH_NAMES, dh_from_degrees
from errors import InputError
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import GaugeLine, Placement, Robot, World
from station.cli import main
from station.formats.tables import load_robot

IRB2600 = configs.path("robots/abb_irb2600.toml")


def _transform(rot: str, angle: float, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler(rot, angle).as_matrix()
    out[:3, 3] = shift
    return out


def craig_chain(mdh_deg: np.ndarray, q_deg: np.ndarray) -> np.ndarray:
    """Base-to-flange pose by Craig's definition, elementary transforms composed with scipy:
    ``Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i)``."""
    pose = np.eye(4)
    for (theta, d, a, alpha), q in zip(mdh_deg, q_deg, strict=True):
        pose = pose @ _transform("x", np.radians(alpha)) @ _transform("x", 0.0, (a, 0, 0))
        pose = pose @ _transform("z", np.radians(theta + q)) @ _transform("z", 0.0, (0, 0, d))
    return pose


def test_a_modified_table_computes_as_craigs_chain():
    rng = np.random.default_rng(7)
    robot = load_robot(IRB2600)
    assert robot.convention == "mdh"
    for _ in range(20):
        q = rng.uniform(-180, 180, 6)
        flange = base_from_frames(robot.model().dh, np.radians(q)[None])[0, 6]
        np.testing.assert_allclose(flange, craig_chain(robot.file_table_deg(), q), atol=1e-9)
    mdh = rng.normal(0, 300, (6, 4))
    mdh[0, 2:] = 0.0
    back, flange = mdh_from_dh(dh_from_mdh(mdh, (12.0, 3.0)))
    np.testing.assert_array_equal(back, mdh)
    assert flange.tolist() == [12.0, 3.0]
    assert [mdh_name(n) for n in ("J1.a_mm", "J5.alpha_deg", "J6.a_mm", "J3.d_mm")] == [
        "J2.a_mm",
        "J6.alpha_deg",
        "flange.a_mm",
        "J3.d_mm",
    ]
    assert [dh_name(mdh_name(n)) for n in DH_NAMES] == list(DH_NAMES)


def test_a_modified_table_places_joint_1_at_the_base(tmp_path):
    text = IRB2600.read_text().replace(
        "alpha_deg = 0.0\na_mm = 0.0\nd_mm = 445.0", "alpha_deg = 0.0\na_mm = 5.0\nd_mm = 445.0"
    )
    (tmp_path / "r.toml").write_text(text)
    with pytest.raises(InputError, match=r'joints.0: alpha_deg 0 and a_mm 5 under convention = "mdh"'):
        load_robot(tmp_path / "r.toml")


def test_link_masses_given_in_craigs_frames_sit_where_the_standard_ones_do(tmp_path):
    """The UR10 (standard, with UR's link masses) written in Craig's convention, each centre of mass
    in Craig's frame at its joint: in the base frame every link's centre lies where the standard
    file puts it, at any reading, so the gravity torques and compliances are the same."""
    ur10 = load_robot(configs.path("robots/ur10.toml"))
    dh = dh_from_degrees(ur10.table_deg())
    mdh, flange = mdh_from_dh(ur10.table_deg())
    com_mdh = com_to_mdh(ur10.link_masses().com_mm, dh)
    joints = [
        {**dict(zip(DH_KEYS, map(float, row), strict=True)), "mass_kg": j.mass_kg, "com_mm": c.tolist()}
        for row, j, c in zip(mdh, ur10.joints, com_mdh, strict=True)
    ]
    flange = {"a_mm": float(flange[0]), "alpha_deg": float(flange[1])}
    data = {"name": "UR10 (mdh)", "convention": "mdh", "joints": joints, "flange": flange}
    (tmp_path / "ur10_mdh.toml").write_text(tomli_w.dumps(data))
    craig = load_robot(tmp_path / "ur10_mdh.toml")
    q = np.random.default_rng(2).uniform(-180, 180, 6)
    frames = base_from_frames(dh, np.radians(q)[None])[0]
    for i in range(6):
        standard = frames[i + 1] @ [*ur10.link_masses().com_mm[i], 1.0]
        at_joint = craig_chain(mdh[: i + 1], q[: i + 1]) @ [*com_mdh[i], 1.0]
        np.testing.assert_allclose(at_joint, standard, atol=1e-9)
    np.testing.assert_allclose(craig.link_masses().com_mm, ur10.link_masses().com_mm, atol=1e-9)


IRB_LINES = (
    GaugeLine(
        0,
        np.array([1000.0, 0, 300]),
        np.array([0, 1.0, 0]),
        500.0,
        np.array([0, 0, 1.0]),
        np.array([0, 0, -1.0]),
    ),
    GaugeLine(
        1,
        np.array([950.0, -450, 600]),
        np.array([1.0, 0, 0]),
        400.0,
        np.array([0, 0, 1.0]),
        np.array([0, 0, -1.0]),
    ),
)


@pytest.fixture(scope="module")
def written_both_ways(tmp_path_factory):
    """The IRB 2600 as shipped (mdh) and as its standard equivalent (dh), a simulated cell around
    it, samples and setup, and each file calibrated by ``station calibrate``."""
    folder = tmp_path_factory.mktemp("mdh")
    mdh = load_robot(IRB2600)
    dh_doc = {
        "name": mdh.name,
        "convention": "dh",
        "tool_mm": list(mdh.tool_mm),
        "joints": [
            {**dict(zip(DH_KEYS, map(float, row), strict=True)), "q_min_deg": lo, "q_max_deg": hi}
            for row, (lo, hi) in zip(mdh.table_deg(), mdh.limits_deg().tolist(), strict=True)
        ],
    }
    (folder / "irb_dh.toml").write_text(tomli_w.dumps(dh_doc))
    nominal = Robot(mdh.table_deg(), np.asarray(mdh.tool_mm, float), mdh.limits_deg())
    world = World.around(nominal, Placement(np.array([800.0, -600, -300]), 200.0, IRB_LINES), seed=4)
    rng = np.random.default_rng(5)
    world.sample_set(40, rng).to_csv(folder / "samples.csv")
    (folder / "setup.toml").write_text(tomli_w.dumps(setup_dict(world, rng)))
    out = {}
    for kind, robot in (("mdh", IRB2600), ("dh", folder / "irb_dh.toml")):
        code = main(
            [
                "calibrate",
                str(folder / "samples.csv"),
                "--robot",
                str(robot),
                "--setup",
                str(folder / "setup.toml"),
                "--out",
                str(folder / f"{kind}.toml"),
                "--report",
                str(folder / f"{kind}.json"),
            ]
        )
        assert code == 0
        out[kind] = (load_robot(folder / f"{kind}.toml"), json.loads((folder / f"{kind}.json").read_text()))
    return world, out, folder


def test_one_robot_written_both_ways_calibrates_to_the_same_tcp(written_both_ways):
    world, out, folder = written_both_ways
    (mdh, mdh_report), (dh, dh_report) = out["mdh"], out["dh"]
    q = np.radians(world.random_configurations(500, np.random.default_rng(1)))
    nominal_mdh, nominal_dh = load_robot(IRB2600).model(), load_robot(folder / "irb_dh.toml").model()
    np.testing.assert_allclose(  # the nominal robot, both ways: the same TCP
        tcp_position(nominal_mdh.dh, q, nominal_mdh.tool), tcp_position(nominal_dh.dh, q, nominal_dh.tool)
    )
    assert mdh.convention == "mdh" and dh.convention == "dh"
    p_mdh = tcp_position(mdh.model().dh, q, mdh.model().tool)
    p_dh = tcp_position(dh.model().dh, q, dh.model().tool)
    assert np.abs(p_mdh - p_dh).max() < 1e-3  # mm: the same calibration, written two ways
    # the report names the parameters as each file does
    assert {mdh.param_name(n) for n in dh_report["identified"]} == set(mdh_report["identified"])
    assert mdh_report["parameters"].keys() == {mdh.param_name(n) for n in dh_report["parameters"]}


def test_the_corrected_modified_table_holds_its_95_percent_bound(written_both_ways):
    world, out, _ = written_both_ways
    mdh, report = out["mdh"]
    q = world.random_configurations(2000, np.random.default_rng(2))
    model = mdh.model()
    true_rmse = _rms(aligned_errors(tcp_position(model.dh, np.radians(q), model.tool), world.true.tcp(q)))
    before = _rms(aligned_errors(world.nominal.tcp(q), world.true.tcp(q)))
    assert true_rmse <= report["workspace"]["predicted_rmse_95_mm"], (true_rmse, report["workspace"])
    assert true_rmse < before / 5


def _rms(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2)))


def test_a_corrected_modified_table_exports_its_own_rows(written_both_ways, capsys):
    _, out, folder = written_both_ways
    assert (
        main(
            [
                "export",
                str(folder / "mdh.toml"),
                "--format",
                "dh-csv",
                "--out",
                str(folder / "t.csv"),
                "--robot",
                str(IRB2600),
            ]
        )
        == 0
    )
    assert "Craig's modified D-H" in capsys.readouterr().out
    rows = np.loadtxt(folder / "t.csv", delimiter=",", skiprows=1)
    mdh = out["mdh"][0]
    np.testing.assert_allclose(rows[:, 1:5], mdh.file_table_deg()[:, [3, 2, 1, 0]], atol=1e-4)
    assert (
        main(["export", str(folder / "mdh.toml"), "--format", "urdf", "--out", str(folder / "r.urdf")]) == 0
    )
