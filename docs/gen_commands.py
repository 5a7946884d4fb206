"""The command reference, one Markdown page per ``station`` command, from ``station.cli``'s argparse
parser: what ``station COMMAND --help`` prints and a table of its options (``docs/hooks.py`` adds
the pages to the site at build time)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def parser() -> argparse.ArgumentParser:
    from station.cli import build_parser

    return build_parser()


def subcommands(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """A parser's subcommands by name, in the order it lists them (none: {})."""
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def command_names() -> list[str]:
    return list(subcommands(parser()))


def options(p: argparse.ArgumentParser) -> list[argparse.Action]:
    """What a user can give a parser (``--help`` and subcommand choices left out)."""
    hidden = argparse._HelpAction | argparse._SubParsersAction
    return [a for a in p._actions if not isinstance(a, hidden) and a.help != argparse.SUPPRESS]


def option_name(action: argparse.Action) -> str:
    """``--out`` / ``-o, --out`` for an option, its metavar (``SAMPLES``) for a positional."""
    if action.option_strings:
        return ", ".join(action.option_strings)
    return action.metavar if isinstance(action.metavar, str) else action.dest


def summaries(p: argparse.ArgumentParser) -> dict[str, str]:
    """{subcommand: the one line ``--help`` lists it with}."""
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {choice.dest: choice.help or "" for choice in action._choices_actions}
    return {}


def top_help() -> str:
    """``station --help``."""
    return _usage(parser())


def index() -> str:
    """A Markdown list linking every command's page (from the commands' index page)."""
    lines = summaries(parser())
    return "\n".join(f"- [`station {name}`]({name}.md): {_cell(text)}" for name, text in lines.items())


def pages() -> dict[str, str]:
    """{command: its page's Markdown} for every ``station`` command."""
    top = parser()
    lines = summaries(top)
    return {name: _page(name, p, lines.get(name, "")) for name, p in subcommands(top).items()}


def _page(name: str, p: argparse.ArgumentParser, summary: str) -> str:
    parts = [f"# station {name}\n", _sentence(summary), _usage(p), _table(p)]
    lines = summaries(p)
    for sub_name, sub in subcommands(p).items():  # `station sim serve`
        lead = _sentence(lines.get(sub_name, ""))
        parts += [f"## station {name} {sub_name}\n", lead, _usage(sub), _table(sub)]
    return "\n".join(part for part in parts if part)


def _sentence(summary: str) -> str:
    """``--help``'s one line for a command as the page's first sentence."""
    text = _cell(summary)
    return f"{text[:1].upper()}{text[1:]}.\n" if text else ""


def _usage(p: argparse.ArgumentParser) -> str:
    """``--help`` as a terminal 100 columns wide prints it."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        text = p.format_help()
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old
    return f"```text\n$ {p.prog} --help\n{text.rstrip()}\n```\n"


def _table(p: argparse.ArgumentParser) -> str:
    rows = ["| option | value | default | what it does |", "|---|---|---|---|"]
    formatter = p._get_formatter()
    for a in options(p):
        what = _cell(formatter._expand_help(a) if a.help else "")
        rows.append(f"| `{option_name(a)}` | {_value(a)} | {_default(a)} | {what} |")
    return "\n".join(rows) + "\n" if len(rows) > 2 else ""


def _value(a: argparse.Action) -> str:
    if a.nargs == 0:
        return "(flag)"
    if a.choices:
        return " \\| ".join(f"`{c}`" for c in a.choices)
    if not a.option_strings:
        return "(positional)"
    metavar = a.metavar if isinstance(a.metavar, str) else a.dest.upper()
    return f"`{metavar}`"


def _default(a: argparse.Action) -> str:
    if a.default in (None, False, argparse.SUPPRESS) or a.nargs == 0:
        return ""
    if isinstance(a.default, Path) and a.default.is_relative_to(ROOT):  # a shipped file, not this checkout's
        return f"`{a.default.relative_to(ROOT)}` (shipped)"
    return f"`{a.default}`"


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")
