"""The documentation: the site builds with ``mkdocs build --strict`` (no broken link, no page left out
of the nav), every ``station`` command has a reference page listing every option its parser takes,
every key of the files' models is in their reference page, every section the README had lives on in
the site, and the README stays a landing page holding the set-up and test commands."""

from __future__ import annotations

import argparse
import ast
import html
import inspect
import re
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
SET_UP = "python3 -m venv .venv && . .venv/bin/activate && pip install -e '.[dev]' && station demo"
TESTS = (
    ". .venv/bin/activate && python -m pytest -q ",
    ". .venv/bin/activate && python -m pytest -q -m system",
    ". .venv/bin/activate && python -m pytest -q -m guard",
)
FORMER_README_SECTIONS = (  # the README's sections before it became a landing page (issue 38)
    "Set up (fresh machine, Python >= 3.10)", "The guard tier (`pytest -m guard`, in CI)",
    "The operator's workflow (what `station demo` shows)", "The pipeline", "Commands",
    "Your own cell", "Hostile inputs, device faults, a full disk", "What the data can and cannot determine",
    "Beyond geometry: joint-space terms (`station calibrate --model`)",
    "Results (simulated HSR-JR680, truth known)", "Planning before measuring (`station plan`)",
    "Measurement programs (`station program`)", "Using the result",
    "Is it still calibrated? (`station verify`, `station history`)",
    "The calibration certificate (`station report`)", "Real robot: UR10, laser tracker (IPA dataset)",
    "Speed (benchmarks/, one run on the 2-core machine, medians; machine shared and loaded)",
    "The paper's comparison (simulated, one line, 200 samples)", "Not done yet",
)  # fmt: skip
FILE_MODELS = {  # reference page -> the model whose every key it lists, its nested tables too
    "reference/files/robot": ("station.formats.tables:RobotFile", True),
    "reference/files/setup": ("station.formats.tables:SetupFile", True),
    "reference/files/station-config": ("station.config:StationConfig", True),
    "reference/files/session-folder": ("station.formats.session_folder:SessionHeader", False),
}


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site, built as CI builds it (strict: any warning fails)."""
    pytest.importorskip("mkdocs", reason="mkdocs is not installed: pip install -e '.[docs]'")
    pytest.importorskip("material", reason="mkdocs-material is not installed: pip install -e '.[docs]'")
    from mkdocs.commands.build import build
    from mkdocs.config import load_config

    out = tmp_path_factory.mktemp("site")
    build(load_config(str(ROOT / "mkdocs.yml"), site_dir=str(out), strict=True))
    return out


def _text(site: Path, page: str) -> str:
    return html.unescape((site / page / "index.html").read_text())


def _parsers():
    """``(name, parser)`` for every command and subcommand of ``station``."""
    from station.cli import build_parser

    def walk(p, prefix):
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield f"{prefix}{name}".strip(), sub
                    yield from walk(sub, f"{prefix}{name} ")

    return list(walk(build_parser(), ""))


def test_every_command_has_a_page_listing_every_option(site):
    parsers = _parsers()
    assert {"calibrate", "sim serve", "import-ipa"} <= {name for name, _ in parsers}
    for name, p in parsers:
        page = _text(site, f"reference/commands/{name.split()[0]}")
        assert f"station {name}" in page, name
        for action in p._actions:
            for flag in action.option_strings:
                assert flag in page, f"station {name}: {flag} is not on its page"
            if not action.option_strings and not isinstance(action, argparse._SubParsersAction):
                assert (action.metavar or action.dest) in page, f"station {name}: {action.dest}"


def _schema_keys(schema: dict, nested: bool) -> set[str]:
    """Every property name of a JSON schema and, if ``nested``, of its definitions (nested tables)."""
    keys = set(schema.get("properties", {}))
    for definition in schema.get("$defs", {}).values() if nested else ():
        keys |= set(definition.get("properties", {}))
    return keys


@pytest.mark.parametrize("page", sorted(FILE_MODELS))
def test_every_key_of_a_file_is_in_its_reference(site, page):
    import importlib

    target, nested = FILE_MODELS[page]
    module, name = target.split(":")
    model = getattr(importlib.import_module(module), name)
    text = _text(site, page)
    rows = set(re.findall(r"<td><code>(\w+)</code></td>", text))
    tables = {path.split(".")[-1] for path in re.findall(r"<code>\[\[?([\w.]+)\]\]?</code>", text)}
    missing = _schema_keys(model.model_json_schema(), nested) - rows - tables
    assert not missing, f"{page}: no row for {sorted(missing)}"


def _written_keys(*functions) -> set[str]:
    """The literal keys of the dicts the ``as_json`` functions build (``{"verdict": ...}``)."""
    keys = set()
    for function in functions:
        for node in ast.walk(ast.parse(textwrap.dedent(inspect.getsource(function)))):
            for key in node.keys if isinstance(node, ast.Dict) else ():
                if isinstance(key, ast.Constant) and isinstance(key.value, str):
                    keys.add(key.value)
    return keys


def test_every_key_a_report_writes_is_in_its_reference(site):
    from station.jobs import report, verification

    provenance = report.Provenance.as_json
    pages = {
        "report": _written_keys(report.CalibrationReport.as_json, report.FitMetrics.as_json, provenance),
        "reference/files/verification": _written_keys(verification.VerifyReport.as_json, provenance),
    }
    for page, keys in pages.items():
        text = _text(site, page)
        missing = sorted(k for k in keys if f"<code>{k}</code>" not in text and f'"{k}"' not in text)
        assert not missing, f"{page}: {missing} not described"


def test_every_former_readme_section_is_a_heading_of_the_site():
    headings = set()
    for page in (ROOT / "docs").rglob("*.md"):
        headings |= {h.strip() for h in re.findall(r"^#{1,6} (.+)$", page.read_text(), flags=re.M)}
    missing = [s for s in FORMER_README_SECTIONS if not any(h.startswith(s) for h in headings)]
    assert not missing, f"sections no page holds: {missing}"


def test_the_readme_is_a_landing_page_with_the_set_up_commands():
    text = README.read_text()
    assert len(text.splitlines()) <= 300
    assert SET_UP in text
    for command in TESTS:
        assert command in text, command
    steps = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if not line.startswith("#")]
    assert "python -m pytest -q" in steps, "CI runs the README's test command"
    first = ("ruff", "mkdocs", "python -m pytest")
    order = [next(i for i, s in enumerate(steps) if s.startswith(c)) for c in first]
    assert order == sorted(order), "CI builds the docs after ruff and before the tests"
