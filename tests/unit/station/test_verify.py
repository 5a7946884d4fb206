"""``station verify`` and ``station history`` on a simulated cell that really changed: a fresh
session of the calibrated cell holds, the cell with J2's link 0.3 mm longer drifts and names it; a
history of three calibrations flags that change and nothing else; the database survives two
writers and refuses a damaged or foreign file without losing a record."""

import json
import multiprocessing
import sqlite3

import numpy as np
import pytest

import configs
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import World
from station import history
from station.cli import main
from station.formats.tables import load_robot, load_setup
from station.jobs.planning import verify_design

SEED = 1
CHANGE = {"J2.a_mm": 0.3}
TRAIN_PER_LINE = 70
VERIFY_POSES = 60  # one line: 40/40 cells caught with 60 poses, 33/40 with 30 (benchmarks/verify_drift.py)
ROBOT = configs.path("robots/hsr_jr680.toml")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A calibrated simulated cell (3 lines x 60 poses, 5 readings per capture), its table written
    by ``station calibrate``, and verification sessions on a 60-pose plan: the cell as it was, and
    after J2's link grew by 0.3 mm."""
    folder = tmp_path_factory.mktemp("verify")
    world = World.create(SEED)
    rng = np.random.default_rng([SEED, 1])
    import tomli_w

    (folder / "setup.toml").write_text(tomli_w.dumps(setup_dict(world, rng)))
    world.sample_set(TRAIN_PER_LINE, rng, readings=5).to_csv(folder / "train.csv")
    sim_setup = load_setup(configs.path("setups/sim.toml"))
    plan = verify_design(load_robot(ROBOT), sim_setup, n_select=VERIFY_POSES).plan
    for name, w in (("fresh", world), ("changed", world.changed(CHANGE))):
        q, lines = w.touch_lines(plan.q_deg, plan.line, rng)
        w.measure(q, lines, rng, readings=5).to_csv(folder / f"{name}.csv")
    w = world.changed(CHANGE)
    w.sample_set(TRAIN_PER_LINE, rng, readings=5).to_csv(folder / "train-changed.csv")
    world.sample_set(TRAIN_PER_LINE, rng, readings=5).to_csv(folder / "train-again.csv")
    db = folder / "cell.sqlite"
    args = ["--robot", str(ROBOT), "--setup", str(folder / "setup.toml"), "--db", str(db)]
    assert main(["calibrate", str(folder / "train.csv"), "--out", str(folder / "table.toml"), *args]) == 0
    return folder, args


def _verify(folder, args, samples, table, capsys):
    code = main(
        ["verify", str(folder / samples), "--table", str(table), *args, "--report", str(folder / "v.json")]
    )
    out = capsys.readouterr().out
    return code, json.loads((folder / "v.json").read_text()), out


def test_a_fresh_session_of_the_calibrated_cell_holds(cell, capsys):
    folder, args = cell
    code, report, out = _verify(folder, args, "fresh.csv", folder / "table.toml", capsys)
    assert code == 0 and report["verdict"] == "holds", out
    assert report["likely"] == []
    # what an unchanged robot leaves: within a few tenths of the stated noise (joint noise adds ~15 %)
    assert 0.7 < report["noise_ratio"] < 1.5
    assert {"rmse_mm", "mean_mm", "max_mm", "noise_ratio", "lines", "likely"} <= set(report)
    assert [ln["id"] for ln in report["lines"]] == [2]


def test_what_a_holding_verification_could_miss_is_caught_when_it_happens(cell, capsys, tmp_path):
    """A verification that holds names the drift it could let pass (the change it catches nine times
    in ten that moves the tool most); the same cell with a quarter more than that change, measured
    on the same plan, is caught."""
    folder, args = cell
    code, report, out = _verify(folder, args, "fresh.csv", folder / "table.toml", capsys)
    missed = report["missed"]
    assert code == 0 and missed["change"] > 0 and missed["workspace_mm"] > 0
    assert f"could miss a drift moving the tool up to {missed['workspace_mm']:.3f} mm" in out
    world, rng = World.create(SEED), np.random.default_rng([SEED, 7])
    plan = verify_design(
        load_robot(ROBOT), load_setup(configs.path("setups/sim.toml")), n_select=VERIFY_POSES
    ).plan
    changed = world.changed({missed["param"]: 1.25 * missed["change"]})
    q, lines = changed.touch_lines(plan.q_deg, plan.line, rng)
    changed.measure(q, lines, rng, readings=5).to_csv(tmp_path / "missed.csv")
    code, report, out = _verify(tmp_path, args, "missed.csv", folder / "table.toml", capsys)
    assert code == 3 and report["verdict"] == "drifted", out


def test_the_cell_after_a_bent_link_drifts_and_names_it(cell, capsys):
    folder, args = cell
    code, report, out = _verify(folder, args, "changed.csv", folder / "table.toml", capsys)
    assert code == 3 and report["verdict"] == "drifted", out
    named = {p["param"]: p for p in report["likely"]}
    assert "J2.a_mm" in named
    j2 = named["J2.a_mm"]
    assert abs(j2["change"] - 0.3) < 3 * j2["sigma"]  # the change it names is the one made
    assert "J2.a_mm" in out


def test_the_nominal_table_drifts_on_the_same_session(cell, capsys):
    folder, args = cell
    code, report, _ = _verify(folder, args, "fresh.csv", ROBOT, capsys)
    assert code == 3 and report["noise_ratio"] > 10


def test_verify_bad_input_is_one_line_and_exit_2(cell, capsys, tmp_path):
    folder, args = cell
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n")
    assert main(["verify", str(folder / "fresh.csv"), "--table", str(bad), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err


def test_three_calibrations_flag_the_change_and_nothing_else(cell, capsys):
    folder, args = cell
    db = folder / "three.sqlite"
    args = [*args[:-1], str(db)]
    for k, name in enumerate(("train.csv", "train-again.csv", "train-changed.csv")):
        assert main(["calibrate", str(folder / name), "--out", str(folder / f"t{k}.toml"), *args]) == 0
    capsys.readouterr()
    assert main(["history", "HSR-JR680", "--db", str(db), "--json", "--plot", str(folder / "h.png")]) == 0
    data = json.loads(capsys.readouterr().out.split("\nwrote ")[0])
    assert len(data["records"]) == 3
    moved = data["moved"]
    assert [m["param"] for m in moved] == ["J2.a_mm"], moved
    assert moved[0]["record"] == data["records"][2]["id"]
    assert abs(moved[0]["change"] - 0.3) < 0.1
    assert (folder / "h.png").stat().st_size > 0


def _record(k: int) -> history.Record:
    return history.Record(
        "R1", "robot", f"2026-01-01T00:00:{k:02d}+00:00", "verify", f"s{k}", "t", "", "holds", 0.1, {}
    )


def _writer(db, base: int, count: int) -> None:
    for k in range(count):
        history.append(db, _record(base + k % 10))


def test_two_writers_at_once_lose_no_record(tmp_path):
    """Two stations (processes) appending to one new database at the same time."""
    db = tmp_path / "shared.sqlite"
    context = multiprocessing.get_context("fork")
    writers = [context.Process(target=_writer, args=(db, base, 60)) for base in (0, 10)]
    for w in writers:
        w.start()
    for w in writers:
        w.join(60)
    assert [w.exitcode for w in writers] == [0, 0]
    found = history.records(db, "R1")
    assert len(found) == 120 and len({r["id"] for r in found}) == 120


def test_a_truncated_database_is_refused_and_left_as_it_was(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    for k in range(200):
        history.append(db, _record(k % 60))
    conn = sqlite3.connect(db)
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    conn.close()
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    truncated = db.read_bytes()
    assert main(["history", "R1", "--db", str(db)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(db) in err and ("damaged" in err or "not a readable" in err)
    with pytest.raises(Exception, match="damaged|not a readable"):
        history.append(db, _record(1))
    assert db.read_bytes() == truncated


def test_a_foreign_sqlite_file_is_refused(tmp_path, capsys):
    db = tmp_path / "other.sqlite"
    conn = sqlite3.connect(db)
    conn.execute("CREATE TABLE t (x)")
    conn.commit()
    conn.close()
    assert main(["history", "--db", str(db)]) == 2
    assert "not a station history" in capsys.readouterr().err


def test_a_robots_serial_is_its_identity_in_the_history(cell, tmp_path, capsys):
    folder, args = cell
    robot = tmp_path / "robot.toml"
    robot.write_text('serial = "JR680-0042"\n' + ROBOT.read_text())
    db = tmp_path / "serial.sqlite"
    flags = ["--robot", str(robot), "--setup", str(folder / "setup.toml"), "--db", str(db)]
    assert main(["calibrate", str(folder / "train.csv"), "--out", str(tmp_path / "t.toml"), *flags]) == 0
    assert load_robot(tmp_path / "t.toml").serial == "JR680-0042"  # the table carries it on
    assert main(["verify", str(folder / "fresh.csv"), "--table", str(tmp_path / "t.toml"), *flags[2:]]) == 0
    capsys.readouterr()
    assert main(["history", "--db", str(db), "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert [(r["robot"], r["name"], r["records"]) for r in found] == [("JR680-0042", "HSR-JR680", 2)]
    assert (
        main(
            [
                "calibrate",
                str(folder / "train.csv"),
                "--out",
                str(tmp_path / "u.toml"),
                *flags,
                "--no-history",
            ]
        )
        == 0
    )
    assert len(history.records(db, "JR680-0042")) == 2


def test_the_simulated_robot_changes_only_the_named_parameter():
    from station.config import SimConfig

    world = World.create(SEED)
    changed = world.changed(CHANGE)
    diff = changed.true.table_deg - world.true.table_deg
    assert diff[1, 2] == pytest.approx(0.3) and np.count_nonzero(diff) == 1
    assert SimConfig(change={"J2.a_mm": 0.3}).change == CHANGE
    with pytest.raises(ValueError, match="J2.b_mm"):
        SimConfig(change={"J2.b_mm": 0.3})


def test_a_damaged_history_keeps_the_calibration_and_says_so(cell, tmp_path, capsys):
    folder, args = cell
    db = tmp_path / "damaged.sqlite"
    db.write_bytes(b"SQLite format 3\x00" + bytes(200))
    flags = [*args[:-1], str(db)]
    assert main(["calibrate", str(folder / "train.csv"), "--out", str(tmp_path / "t.toml"), *flags]) == 0
    err = capsys.readouterr().err
    assert (tmp_path / "t.toml").exists() and err.startswith("station: history not written: ")
    assert err.count("\n") == 1 and str(db) in err
    assert db.read_bytes() == b"SQLite format 3\x00" + bytes(200)


def test_plan_verify_writes_a_short_plan_on_one_line(tmp_path, capsys):
    out = tmp_path / "check.csv"
    setup = str(configs.path("setups/sim.toml"))
    assert main(["plan", "--verify", "12", "--robot", str(ROBOT), "--setup", setup, "--out", str(out)]) == 0
    rows = out.read_text().splitlines()
    assert rows[0].startswith("target,line,q1_deg") and len(rows) == 13
    assert len({r.split(",")[1] for r in rows[1:]}) == 1
    assert "verification plan: 12 poses" in capsys.readouterr().out
