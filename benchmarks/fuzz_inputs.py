"""Hostile inputs at scale: ``--cases`` mutated files, spread over every input the station reads,
each through the command that reads it (``tests/hostile_inputs.py`` has the mutations and the
contract: exit 0 or 2, or 1 where a valid input reaches the absent devices; one stderr line; no
traceback; nothing written on exit 2).

    python benchmarks/fuzz_inputs.py [--cases 2000] [--seed 0] [--json]

Prints a table per input (cases, exits 0/1/2, violations) and the first violations found; with
``--json`` the last line is ``{"cases", "seed", "exits": {code: n}, "by_input": {...},
"violations", "examples", "seconds"}``. Exit status 1 when the contract broke at least once.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.hostile_inputs import TARGETS, make_kit, run_case  # noqa: E402


def fuzz(cases: int, seed_value: int, folder: Path) -> list:
    """Outcomes of ``cases`` cases drawn by Hypothesis from ``seed_value`` (no shrinking: every
    case counts once)."""
    kit = make_kit(folder / "kit")
    outcomes = []

    @seed(seed_value)
    @settings(
        max_examples=cases,
        database=None,
        deadline=None,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def case(data):
        target = data.draw(st.sampled_from(TARGETS))
        outcomes.append(run_case(kit, target, folder / f"case{len(outcomes)}", data.draw))

    case()
    return outcomes


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        outcomes = fuzz(args.cases, args.seed, Path(tmp))
    seconds = time.perf_counter() - t0
    by_input = collections.defaultdict(collections.Counter)
    for o in outcomes:
        by_input[o.target][str(o.code)] += 1
        by_input[o.target]["violations"] += o.violation is not None
    bad = [o for o in outcomes if o.violation]
    print(f"{len(outcomes)} cases, seed {args.seed}, {seconds:.0f} s")
    print("| input | cases | exit 0 | exit 1 (devices) | exit 2 | violations |")
    for target in TARGETS:
        c = by_input[target.name]
        n = sum(v for k, v in c.items() if k != "violations")
        print(f"| {target.name} | {n} | {c['0']} | {c['1']} | {c['2']} | {c['violations']} |")
    for o in bad[:10]:
        print(f"VIOLATION {o.target}: {o.mutation}: {o.violation}")
    if args.json:
        summary = {
            "cases": len(outcomes),
            "seed": args.seed,
            "exits": dict(collections.Counter(str(o.code) for o in outcomes)),
            "by_input": {name: dict(c) for name, c in by_input.items()},
            "violations": len(bad),
            "examples": [f"{o.target}: {o.mutation}: {o.violation}" for o in bad[:5]],
            "seconds": round(seconds, 1),
        }
        print(json.dumps(summary))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
