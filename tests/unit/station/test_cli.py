"""The command line itself: every option explains itself, the top-level help describes the station,
``--version`` names the installed package's version."""

import argparse
import os
from importlib.metadata import version

import pytest

from station.cli import DISTRIBUTION, build_parser, main


def _parsers(parser: argparse.ArgumentParser, path=("station",)):
    """Every parser of the command line with its path: (path, parser), the top level first."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_every_option_and_command_has_help_text():
    missing = []
    for path, parser in _parsers(build_parser()):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                missing += [f"{' '.join(path)} {c.dest}" for c in action._choices_actions if not c.help]
            elif not action.help or action.help == argparse.SUPPRESS:
                missing.append(f"{' '.join(path)} {'/'.join(action.option_strings) or action.dest}")
    assert missing == []
    assert len(list(_parsers(build_parser()))) > 10  # the walk reached the sub-commands


def test_top_level_help_describes_the_station_and_its_workflow(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    text = capsys.readouterr().out
    assert done.value.code == 0
    assert text.splitlines()[2].startswith("Robot calibration station: measure a robot along gauge-block")
    assert "Console script" not in text and "parse, call, print" not in text
    for command in ("plan", "sample", "calibrate", "export", "compensate", "demo", "sim", "read"):
        assert f"`station {command}" in text


def test_version_prints_the_installed_package_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    out, err = capsys.readouterr()
    assert done.value.code == 0 and err == ""
    assert out == f"station {version(DISTRIBUTION)}\n"
    assert version(DISTRIBUTION)[0].isdigit()


def test_one_blas_thread_unless_the_environment_says_otherwise(monkeypatch, capsys):
    # set before numpy loads (the commands import it in run): a user's own setting stands
    for key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.setenv(key, "x")  # recorded, so the test's changes are undone
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    monkeypatch.setenv("OMP_NUM_THREADS", "4")
    with pytest.raises(SystemExit):
        main(["--version"])
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1" and os.environ["OMP_NUM_THREADS"] == "4"
