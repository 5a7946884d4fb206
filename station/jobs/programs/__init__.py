"""``station program``'s writers, one module per controller language, and their one table
(``FORMATS``: name -> module, file extension, help), as meshio registers its formats.

Every writer takes a :class:`~station.jobs.programs.common.Program` (the measurement, the robot,
the plan's name, the motion, ``--out``) and writes one contact point per plan target, in plan order
(a target without a stand-off left out with a comment), each target's id and gauge line in a
comment beside its moves, joints in degrees in the controller's convention (the robot file's
``[controller]``: ``reading = joint_sign * (q_model - joint_offset_deg)``), every name that reaches
the program escaped for that language. No real controller has checked these programs: they follow
the vendors' manuals, and ``sim_fixtures.programs`` reads them back. A writer module has
``paths(out)`` (the files it writes for ``--out``, its names checked: InputError) and
``write(program)`` (their texts, in that order).

This module imports nothing heavy: the command's parser lists the formats from it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ProgramFormat:
    """A program format: the writer ``module`` (in this package), the usual file ``extension``,
    and a ``help`` line for the command's ``--help``."""

    module: str
    extension: str
    help: str


FORMATS = {
    "urscript": ProgramFormat(
        "urscript", ".script", "Universal Robots URScript, taking corrected targets over RTDE"
    ),
    "poses-csv": ProgramFormat("poses_csv", ".csv", "every pose and joint set as CSV, for any controller"),
    "krl": ProgramFormat("krl", ".src", "KUKA KRL: the .src and its .dat beside it (E6AXIS points)"),
    "rapid": ProgramFormat("rapid", ".mod", "ABB RAPID module (jointtargets, MoveAbsJ, MoveL)"),
    "fanuc-ls": ProgramFormat("fanuc", ".ls", "Fanuc TP program in its ASCII .ls form (joint positions)"),
}


def _module(name: str):
    return importlib.import_module(f"{__name__}.{FORMATS[name].module}")


def paths(name: str, out: Path) -> list[Path]:
    """The files format ``name`` writes for ``--out`` ``out`` (InputError: a name the controller
    cannot take)."""
    return list(_module(name).paths(Path(out)))


def write(name: str, program) -> list[tuple[Path, str]]:
    """Each file of ``program`` (a ``common.Program``) in format ``name``, with its text."""
    module = _module(name)
    return list(zip(module.paths(program.out), module.write(program), strict=True))
