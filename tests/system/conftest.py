"""System tests: real sockets, pseudo-terminals and subprocesses. Every test here is marked
``system`` (``pytest -m "not system"`` runs the unit tests alone)."""

import pathlib

import pytest

HERE = pathlib.Path(__file__).parent


def pytest_collection_modifyitems(items):
    for item in items:
        if HERE in pathlib.Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.system)
