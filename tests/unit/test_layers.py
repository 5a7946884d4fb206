"""Imports run one way: errors, configs <- calib <- drivers <- sim_fixtures <- station.

Parsed with ``ast`` (every import statement, also those inside functions), so a violation names
the file, the line and the import. Only the ``demo`` and ``sim`` commands may reach the simulator.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LAYER = {"errors": 0, "configs": 0, "calib": 1, "drivers": 2, "sim_fixtures": 3, "station": 4}
MAY_IMPORT_SIM = {"station/commands/demo.py", "station/commands/sim.py"}


def imports_of(path: Path):
    """(line, top-level package) of every import of ours in ``path``."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            if top in LAYER:
                yield node.lineno, name


def violations(root: Path = ROOT) -> list[str]:
    found = []
    for package, level in LAYER.items():
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            for line, name in imports_of(path):
                top = name.split(".")[0]
                if LAYER[top] > level:
                    found.append(f"{rel}:{line}: imports {name} (layer {top} sits above {package})")
                elif package == "station" and top == "sim_fixtures" and rel not in MAY_IMPORT_SIM:
                    found.append(f"{rel}:{line}: imports {name} (only the demo and sim commands may)")
    return found


def test_imports_run_one_way():
    assert violations() == []


def test_the_check_sees_a_violation(tmp_path):
    (tmp_path / "calib").mkdir()
    leak = "def f():\n    from station.formats.tables import load_robot\n"
    (tmp_path / "calib" / "leak.py").write_text(leak)
    (tmp_path / "station" / "jobs").mkdir(parents=True)
    (tmp_path / "station" / "jobs" / "x.py").write_text("import sim_fixtures.world\n")
    assert violations(tmp_path) == [
        "calib/leak.py:2: imports station.formats.tables (layer station sits above calib)",
        "station/jobs/x.py:1: imports sim_fixtures.world (only the demo and sim commands may)",
    ]
