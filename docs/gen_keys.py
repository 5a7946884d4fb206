"""Key tables of the station's files, from their pydantic models: every key with its type, default,
unit, range and description (``docs/hooks.py`` puts them where a page says ``<!-- keys M:C -->``).

A description is the comment the commented example file (``configs/...``, the marker's second word)
writes on that key, else the comment beside the field in the model's source, else what the model's
docstring says of it, else its ``Field(description=...)``. A nested model is a table of its own
(``[session]``, ``[[joints]]``); a union of models (the robot's ``kind``) one table per kind.
"""

from __future__ import annotations

import importlib
import inspect
import io
import re
import tokenize
import types
import typing
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

ROOT = Path(__file__).resolve().parent.parent
UNITS = (  # by the key's ending, longest first
    ("_urad_per_Nm", "urad/(N m)"), ("_deg_s2", "deg/s²"), ("_deg_s", "deg/s"), ("_mm", "mm"),
    ("_deg", "deg"), ("_hz", "Hz"), ("_kg", "kg"), ("_s", "s"),
)  # fmt: skip
BOUNDS = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<", "min_length": "length >=", "max_length": "length <="}


@dataclass(frozen=True)
class Table:
    """One TOML table of a file: its ``title`` (``[session]``), the model's ``doc`` and its ``rows``
    (key, type, default, unit, range, description)."""

    title: str
    doc: str
    rows: list[tuple[str, str, str, str, str, str]]


def model(target: str):
    """``station.config:StationConfig`` -> the class (any module attribute)."""
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def tables(cls: type[BaseModel], example: str | None = None) -> list[Table]:
    """Every table of ``cls``, the top level first; ``example`` ``flat``: the top level alone, its
    nested tables as rows (a page that links to their own reference)."""
    flat = example == "flat"
    comments = example_comments(ROOT / example) if example and not flat else {}
    out: list[Table] = []
    _walk(cls, "", "", comments, out, flat)
    return out


def markdown(target: str, example: str | None = None) -> str:
    """The key tables of the model ``target`` (``module:Class``) as Markdown."""
    parts = []
    for t in tables(model(target), example):
        head = f"### {t.title}\n\n{t.doc}\n\n" if t.title else f"{t.doc}\n\n"
        rows = "\n".join("| " + " | ".join(_escape(c) for c in r) + " |" for r in t.rows)
        parts.append(
            head + "| key | type | default | unit | range | what it is |\n|---|---|---|---|---|---|\n" + rows
        )
    return "\n\n".join(parts)


def _walk(cls, path: str, kind: str, comments: dict, out: list[Table], flat: bool = False) -> None:
    rows, nested = [], []
    source = source_comments(cls)
    for name, field in cls.model_fields.items():
        inner = _models(field.annotation)
        if inner and not flat:
            nested.append((name, field.annotation, inner))
            continue
        describe = (
            comments.get((path, kind, name))
            or comments.get((path, "", name))
            or comments.get(("*", "", name))
            or source.get(name)
            or _docstring_says(cls, name)
        )
        rows.append(
            (
                f"`{name}`",
                type_name(field.annotation),
                _default(field),
                _unit(name),
                _range(field.metadata),
                describe or field.description or (_doc(inner[0]) if inner else ""),
            )
        )
    if rows:
        title = f"`[{path}]`" + (f' with `kind = "{kind}"`' if kind else "") if path else ""
        out.append(Table(title, _doc(cls), rows))
    for name, annotation, inner in nested:
        sub = f"{path}.{name}" if path else name
        many = typing.get_origin(_strip(annotation)) is list
        for m in inner:
            k = _kind(m) if len(inner) > 1 else kind  # a kind's own tables say whose they are
            _walk(m, f"[{sub}]" if many else sub, k, comments, out)


def _strip(annotation):
    """``Annotated[X, ...]`` and ``X | None`` -> X."""
    while typing.get_origin(annotation) is typing.Annotated:
        annotation = typing.get_args(annotation)[0]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return _strip(args[0])
    return annotation


def _models(annotation) -> list[type[BaseModel]]:
    """The models a field holds as a table (itself, a list of them, one of a union of them)."""
    a = _strip(annotation)
    if typing.get_origin(a) is list:
        a = _strip(typing.get_args(a)[0])
    options = typing.get_args(a) if typing.get_origin(a) in (typing.Union, types.UnionType) else (a,)
    options = [_strip(o) for o in options if o is not type(None)]
    return options if all(inspect.isclass(o) and issubclass(o, BaseModel) for o in options) else []


def _kind(m: type[BaseModel]) -> str:
    return typing.get_args(_strip(m.model_fields["kind"].annotation))[0]


def type_name(annotation) -> str:
    a = _strip(annotation)
    origin, args = typing.get_origin(a), typing.get_args(a)
    if origin is typing.Literal:
        return " or ".join(f'"{v}"' if isinstance(v, str) else str(v) for v in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(type_name(x) for x in args if x is not type(None))
    if origin in (list, tuple):
        return f"list of {type_name(args[0])}" if args else "list"
    if origin is dict:
        return f"table of {type_name(args[1])}" if args else "table"
    if a is dict or (inspect.isclass(a) and issubclass(a, BaseModel)):
        return "table"
    plain = {str: "text", float: "number", int: "whole number", bool: "true or false"}
    return plain.get(a, getattr(a, "__name__", str(a)))


def _default(field) -> str:
    if field.default is PydanticUndefined and field.default_factory is None:
        return "required"
    value = field.default_factory() if field.default is PydanticUndefined else field.default
    if value is None:
        return "(none)"
    if isinstance(value, BaseModel):
        return "(its table's defaults)"
    return f"`{_toml(value)}`"


def _toml(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    return str(value)


def _unit(name: str) -> str:
    return next((unit for end, unit in UNITS if name.endswith(end)), "")


def _range(metadata) -> str:
    found = []
    for m in metadata:
        for attr, word in BOUNDS.items():
            if getattr(m, attr, None) is not None:
                found.append(f"{word} {getattr(m, attr)}")
        if getattr(m, "pattern", None):
            found.append(f"matches `{m.pattern}`")
    return ", ".join(found)


def _doc(cls) -> str:
    doc = _plain(inspect.getdoc(cls) or "")
    return " ".join(doc.split("\n\n")[0].split())


def _plain(doc: str) -> str:
    """A docstring without Sphinx's roles (``:meth:`x``` reads as ```x```: Markdown has no roles)."""
    return re.sub(r":(?:meth|func|class|attr|mod|data):`", "`", doc)


def _docstring_says(cls, name: str) -> str:
    """What the model's docstring says of ``name``: after "``name``: " up to ``;`` or a sentence's end."""
    doc = " ".join(_plain(inspect.getdoc(cls) or "").split())
    found = re.search(rf"``{name}``: (.+?)(?:; |\. |\.$|$)", doc)
    return found.group(1) if found else ""


def _escape(cell: str) -> str:
    return cell.replace("|", "\\|").replace("\n", " ")


def source_comments(cls) -> dict[str, str]:
    """{field: the comment beside it, or on the lines just above it} in the class's source."""
    try:
        lines = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):
        return {}
    found, above = {}, []
    for line in lines[1:]:
        stripped = line.strip()
        if stripped.startswith("#"):
            above.append(stripped.lstrip("# "))
            continue
        match = re.match(r"    (\w+)\s*:", line)
        if match and match.group(1) in cls.model_fields:
            found[match.group(1)] = _trailing(line) or " ".join(above)
        above = []
    return {k: v for k, v in found.items() if v}


def _trailing(line: str) -> str:
    try:
        tokens = list(tokenize.generate_tokens(io.StringIO(line.strip() + "\n").readline))
    except (tokenize.TokenError, IndentationError):
        return ""
    return next((t.string.lstrip("# ") for t in tokens if t.type == tokenize.COMMENT), "")


KEY = re.compile(r"^(#\s*)?([A-Za-z_]\w*)\s*=\s*(.*)$")
# a key explained in prose: `# name: ...`, `#   a_mm  [mm] ...`, `#   q_min_deg, q_max_deg  ...`
PROSE = re.compile(r"^#(\s{1,3})([a-z_]\w*(?:,\s*[a-z_]\w*)*)(?::\s|\s{2,}|\s+(?=\[))(.*)$")
HEADER = re.compile(r"^(?:#\s*)?\[\[?([\w.]+)\]\]?")


def example_comments(path: Path) -> dict[tuple[str, str, str], str]:
    """{(table, kind, key): its comment} in a commented example TOML, commented-out keys too; a
    comment runs on over the indented comment lines below it. ``[[joints]]`` is the table
    ``[joints]``, and ``kind`` the last ``kind = "..."`` met in that table; a key explained in a
    prose comment (``# name: ...``, ``#   a_mm  [mm] ...``, running on over the comment lines
    below it, those of a list item indented further) is filed under the table ``*``."""
    found: dict[tuple[str, str, str], str] = {}
    table, kind, last, prose = "", "", [], None
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if last and _runs_on(raw, line, prose):
            for key in last:
                found[key] += " " + line.lstrip("# ")
            continue
        last, prose = [], None
        if header := HEADER.match(line):
            name = header.group(1)
            table, kind = (f"[{name}]" if line.lstrip("# ").startswith("[[") else name), ""
        elif match := KEY.match(line):
            key, rest = match.group(2), match.group(3)
            if key == "kind":
                kind = rest.split("#")[0].strip().strip('"')
            comment = _trailing(f"x = {rest}")
            if comment and (table, kind, key) not in found:
                last = [(table, kind, key)]
                found[last[0]] = comment
        elif match := PROSE.match(line):
            prose = len(match.group(1))
            keys = [("*", "", k.strip()) for k in match.group(2).split(",")]
            last = [k for k in keys if k not in found]
            found.update(dict.fromkeys(last, match.group(3).strip()))
    return found


def _runs_on(raw: str, line: str, prose: int | None) -> bool:
    """Whether a comment line continues the comment before it: an indented one after a key's
    trailing comment; after a prose one (its key ``prose`` spaces after the ``#``) a comment line
    that starts no other key, indented further where the key was a list item (2 spaces or more)."""
    if not line.startswith("#") or not line.lstrip("# "):
        return False
    if prose is None:
        return raw.startswith(" ")
    body = line[1:]
    indent = len(body) - len(body.lstrip())
    if PROSE.match(line) or KEY.match(line) or HEADER.match(line):
        return False
    return indent > prose if prose > 1 else indent >= prose
