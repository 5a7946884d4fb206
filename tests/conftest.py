"""Shared simulated cells. Generating samples solves the true robot's IK per sample, so each
scenario is written once per test session."""

import numpy as np
import pytest

from sim_fixtures.scenario import write_scenario


@pytest.fixture(scope="session")
def three_lines(tmp_path_factory):
    """3 gauge lines, 50 samples each, 20 hold-out samples per line."""
    return write_scenario(tmp_path_factory.mktemp("three"), seed=3, n_lines=3, n_per_line=50)


@pytest.fixture(scope="session")
def one_line(tmp_path_factory):
    """The paper's setting: one gauge line, 200 samples."""
    return write_scenario(tmp_path_factory.mktemp("one"), seed=4, n_lines=1, n_per_line=200)


@pytest.fixture(scope="session")
def outliers(tmp_path_factory):
    """The three-line cell with 3 % gross drawstring readings (cable slip, 2-5 mm)."""
    return write_scenario(
        tmp_path_factory.mktemp("outl"), seed=3, n_lines=3, n_per_line=50, outlier_fraction=0.03
    )


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(autouse=True)
def history_db(tmp_path_factory, monkeypatch):
    """Every command's history record goes to a database of the test's own, never the user's, and
    outside the test's tmp_path (tests list what a command wrote there)."""
    path = tmp_path_factory.mktemp("history") / "history.sqlite"
    monkeypatch.setenv("STATION_HISTORY_DB", str(path))
    return path
