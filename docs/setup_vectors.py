"""Draw one gauge line of a setup file with its three vectors (``docs/setup-vectors.png``):
``point_mm`` (the centre of the usable edge), ``direction`` and ``length_mm``, ``approach`` (the way
the tool points) and ``dial_axis`` (the way the dial reads positive).

    python docs/setup_vectors.py [--out docs/setup-vectors.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import configs  # noqa: E402
from station.formats.tables import load_setup  # noqa: E402


def draw(out: Path) -> None:
    line = load_setup(configs.path("setups/sim.toml")).lines[0]
    centre = np.array(line.point_mm)
    direction = np.array(line.direction) / np.linalg.norm(line.direction)
    approach = np.array(line.approach) / np.linalg.norm(line.approach)
    dial = np.array(line.dial_axis) / np.linalg.norm(line.dial_axis)
    half = line.length_mm / 2
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    ends = np.array([centre - half * direction, centre + half * direction])
    ax.plot(*ends.T, color="k", lw=4, label=f"the gauge edge: length_mm = {line.length_mm:g}")
    ax.scatter(*centre, color="k", s=40)
    ax.text(*(centre + [0, -60, -70]), "point_mm\n(the edge's centre)", fontsize=9)
    scale = 160.0
    # side by side along the edge: the tool coming onto it, the way the dial reads
    contact, dial_at = centre - 0.45 * half * direction, centre + 0.45 * half * direction
    tool = contact - scale * approach
    arrows = (
        (centre, direction, "tab:blue", "direction (along the edge)"),
        (tool, approach, "tab:red", "approach (the way the tool points)"),
        (dial_at, dial, "tab:green", "dial_axis (the dial reads positive)"),
    )
    for start, vector, colour, label in arrows:
        ax.quiver(*start, *(scale * 0.9 * vector), color=colour, lw=2.5, arrow_length_ratio=0.15, label=label)
    ax.plot(*np.array([tool, tool + 60 * np.array([0, 0, 1.0])]).T, color="tab:gray", lw=8, alpha=0.6)
    ax.text(*(tool + [0, 10, 70]), "tool", fontsize=9, color="tab:gray")
    ax.set(xlabel="x [mm]", ylabel="y [mm]", zlabel="z [mm]")
    ax.set_box_aspect((1, 1, 1))
    span = max(half, scale) * 1.2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - span, c + span)
    ax.view_init(elev=15, azim=-20)
    ax.set_title(
        "A gauge line in the setup file (configs/setups/sim.toml, line 0; base frame)\n"
        "p_TCP - dial_mm * dial_axis lies on the edge; the tool presses against the dial: "
        "dial_axis = -approach",
        fontsize=9,
    )
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("setup-vectors.png"))
    draw(parser.parse_args().out)


if __name__ == "__main__":
    main()
