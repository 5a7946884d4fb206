"""MkDocs hooks (``hooks:`` in mkdocs.yml): the pages the site generates at build time.

- ``reference/commands/<command>.md``, one per ``station`` command: its ``--help`` and a table of its
  options, built from ``station.cli.build_parser()``, so a new command or option appears by itself;
- ``<!-- keys MODULE:CLASS -->`` in a page: the key tables of a file's pydantic model (every key
  with its type, default, unit, range and description; the description from the commented example
  file of that model where it has one, else from the model's source);
- ``<!-- include PATH -->`` in a page: a shipped file shown whole (the commented examples);
- ``<!-- help station -->``: what ``station --help`` prints; ``<!-- commands list -->``: a link to
  every command's page with the line ``--help`` lists it with;
- ``<!-- value MODULE:NAME LANG -->``: a module's constant (the history's SQL layout; a tuple of
  CSV columns as a header line).

The tables come from :mod:`docs.gen_keys`, the command pages from :mod:`docs.gen_commands`; tests
call both (``tests/unit/test_docs.py``).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # the tree being documented, not an installed copy
    sys.path.insert(0, str(ROOT))

from docs import gen_commands, gen_keys  # noqa: E402

COMMANDS_NAV = "Commands"  # the nav entry whose pages are the generated command pages
MARKER = re.compile(r"<!-- (keys|include|help|value|commands) (\S+?)(?: (\S+))? -->")


def on_config(config):
    """Put every command's page under the nav's ``Commands`` entry, in the parser's order."""
    pages = [{f"station {name}": f"reference/commands/{name}.md"} for name in gen_commands.command_names()]
    _expand_nav(config["nav"] or [], pages)
    return config


def _expand_nav(items: list, pages: list) -> None:
    for item in items:
        if not isinstance(item, dict):
            continue
        for title, value in item.items():
            if title == COMMANDS_NAV and isinstance(value, str):
                item[title] = [value, *pages]
            elif isinstance(value, list):
                _expand_nav(value, pages)


def on_files(files, config):
    from mkdocs.structure.files import File

    for name, text in gen_commands.pages().items():
        files.append(File.generated(config, f"reference/commands/{name}.md", content=text))
    return files


def on_page_markdown(markdown, page, config, files):
    return MARKER.sub(_expand_marker, markdown)


def _expand_marker(match: re.Match) -> str:
    kind, target, extra = match.groups()
    if kind == "keys":
        return gen_keys.markdown(target, example=extra)
    if kind == "help":  # `station --help`
        return gen_commands.top_help()
    if kind == "commands":  # a link to every command's page
        return gen_commands.index()
    if kind == "value":  # a module's constant: the history's SQL layout, a CSV's columns
        value = gen_keys.model(target)
        text = value.strip() if isinstance(value, str) else ",".join(value)
        return f"```{extra or 'text'}\n{text}\n```"
    text = (ROOT / target).read_text()
    return f"```{Path(target).suffix.lstrip('.') or 'text'}\n{text.rstrip()}\n```"
