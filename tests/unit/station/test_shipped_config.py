"""The shipped ``configs/station.toml`` documents the whole configuration: every key of every
section of the pydantic models (``station.config``, ``drivers.config``), each alternative device
kind's keys in a commented block under its section, every key at its default and with a comment.
A key added to a model and not to the shipped file fails here."""

import json
import re
import types
import typing
from collections import defaultdict

import tomllib
from pydantic import BaseModel
from pydantic_core import PydanticUndefined

import configs
from station.config import StationConfig, load_station_config

SHIPPED = configs.path("station.toml")
KEY_LINE = re.compile(r"^#?\s*([a-z_][a-z0-9_]*)\s*=\s*\S")


def _members(annotation) -> list[type[BaseModel]]:
    """The models an annotation admits (through Annotated, unions and None)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    if typing.get_origin(annotation) in (typing.Annotated, typing.Union, types.UnionType):
        args = typing.get_args(annotation)
        args = args[:1] if typing.get_origin(annotation) is typing.Annotated else args
        return [m for a in args for m in _members(a)]
    return []


def _expected(model: type[BaseModel], path=()) -> dict:
    """The keys each block must show: ``{(section path, kind or None): {key: field}}``."""
    blocks: dict = defaultdict(dict)
    kind = model.model_fields.get("kind")
    block = (path, typing.get_args(kind.annotation)[0] if kind else None)
    for name, field in model.model_fields.items():
        members = _members(field.annotation)
        if not members:
            blocks[block][name] = field
        for member in members:
            for key, fields in _expected(member, (*path, name)).items():
                blocks[key].update(fields)
    return blocks


def _shipped() -> dict:
    """The shipped file's key lines, active or commented: ``{(section, kind): {key: (value, line)}}``;
    a ``kind = ...`` line starts the block of that kind."""
    blocks: dict = defaultdict(dict)
    section, kind = (), None
    for line in SHIPPED.read_text().splitlines():
        text = line.strip()
        if text.startswith("["):
            section, kind = tuple(text[1 : text.index("]")].split(".")), None
            continue
        found = KEY_LINE.match(text)
        if not found:
            continue
        key, value = next(iter(tomllib.loads(text.lstrip("#").strip()).items()))
        if key == "kind":
            kind = value
        blocks[(section, kind)][key] = (value, text)
    return blocks


def test_every_key_of_every_section_is_in_the_shipped_file_and_nothing_else():
    expected, shipped = _expected(StationConfig), _shipped()
    assert set(shipped) == set(expected)
    for block, fields in expected.items():
        assert set(shipped[block]) == set(fields), block
    assert len(expected) == 14  # top, session, sweep, 4 robots, 3 drawstr., registers, dial, reconnect, sim


def test_every_key_is_at_its_default_and_explained():
    shipped = _shipped()
    for block, fields in _expected(StationConfig).items():
        for key, field in fields.items():
            value, line = shipped[block][key]
            assert re.search(r"\s#\s", line), f"{line!r}: no comment"
            if field.default is not PydanticUndefined:
                assert value == json.loads(json.dumps(field.default)), (block, line)


def test_the_shipped_file_loads_with_its_active_sections():
    cfg = load_station_config(SHIPPED)
    assert (cfg.robot.kind, cfg.drawstring.kind, cfg.dial.dialect) == ("rtde", "modbus_tcp", "sylvac")
    assert cfg.session == StationConfig.model_fields["session"].default
    assert cfg.sim == StationConfig.model_fields["sim"].default


def test_the_shipped_robot_files_say_tool_mm_is_the_tcp_as_the_readme_does():
    """The ABB file said 'tool_mm is the flange', the docs that it is the ball's centre (issue 35)."""
    for path in sorted(configs.path("robots").glob("*.toml")):
        said = [line for line in path.read_text().splitlines() if line.startswith("#") and "tool_mm" in line]
        for line in said:
            assert "is the flange" not in line, (path.name, line)
        assert not said or any("the TCP in the flange frame" in line for line in said), path.name
