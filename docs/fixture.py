"""Draw the measuring fixture of docs/tutorials/own-cell-ur.md (docs/fixture.png): python docs/fixture.py"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Circle, FancyArrowPatch, Rectangle  # noqa: E402


def arrow(ax, start, end, color, text, offset=(0.0, 0.0), **kw):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=14, color=color, lw=2, **kw))
    ax.annotate(text, end, xytext=offset, textcoords="offset points", color=color, fontsize=9)


def main(out: Path) -> None:
    fig, ax = plt.subplots(figsize=(8.0, 5.6), dpi=120)
    # the gauge block, its edge running into the page (the line), and the dial indicator under it
    ax.add_patch(Rectangle((-3.0, -3.0), 3.0, 3.0, color="#b8c4d6", ec="k"))
    ax.text(-2.9, -2.8, "gauge block\n(fixed on the table)", fontsize=9)
    ax.plot(0, 0, marker="o", ms=9, mfc="white", mec="k")
    ax.plot(0, 0, marker=".", ms=4, color="k")
    ax.annotate(
        "edge = gauge line k\n(runs into the page: direction)",
        (0, 0),
        xytext=(-150, -40),
        textcoords="offset points",
        fontsize=9,
    )
    # the tool: flange, stem, ball; the TCP at the ball's centre
    tcp = (0.0, 0.55)
    ax.add_patch(Rectangle((-0.9, 3.6), 1.8, 0.35, color="#888888", ec="k"))
    ax.text(1.0, 3.7, "robot flange (D-H frame 6)", fontsize=9)
    ax.add_patch(Rectangle((-0.12, 1.0), 0.24, 2.6, color="#cccccc", ec="k"))
    ax.add_patch(Circle(tcp, 0.45, color="#f0c040", ec="k", zorder=3))
    ax.plot(*tcp, marker="+", ms=12, color="k", zorder=4)
    ax.annotate(
        "TCP = ball centre\n= tool_mm in the flange frame\n(the cable's eyelet sits here too)",
        tcp,
        xytext=(-205, 8),
        textcoords="offset points",
        fontsize=9,
        arrowprops={"arrowstyle": "-", "color": "k"},
    )
    # the dial indicator's plunger reads along dial_axis, zero with the ball centre on the edge
    ax.add_patch(Rectangle((0.75, -1.4), 0.5, 1.2, color="#9fd39f", ec="k"))
    ax.text(1.4, -1.3, "dial indicator, plunger on the ball\nzero: ball centre on the edge", fontsize=9)
    ax.plot([1.0, 1.0], [-0.2, 0.2], color="k", lw=2)
    ax.plot([1.0, 0.42], [0.2, 0.42], color="k", lw=1)
    arrow(
        ax,
        (2.2, 0.0),
        (2.2, 1.2),
        "tab:green",
        "dial_axis: dial_mm grows\nas the TCP moves this way",
        (6, -6),
    )
    arrow(
        ax, (-2.4, 3.4), (-2.4, 2.2), "tab:red", "approach: the way the\ntool moves onto the edge", (-60, -30)
    )
    # the drawstring: cable from its exit point (anchor) to the TCP
    anchor = (3.6, -2.6)
    ax.plot([anchor[0], tcp[0]], [anchor[1], tcp[1]], color="tab:blue", lw=1.5, ls="--")
    ax.add_patch(Rectangle((anchor[0] - 0.25, anchor[1] - 0.35), 0.5, 0.35, color="tab:blue"))
    ax.text(
        anchor[0] - 0.9,
        anchor[1] - 0.75,
        "drawstring: exit point = anchor_mm\nlength_mm = |TCP - anchor| - offset",
        fontsize=9,
        color="tab:blue",
    )
    ax.set_xlim(-4.2, 5.2)
    ax.set_ylim(-3.6, 4.2)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("The measuring fixture, across the edge: one TCP for the cable and the dial", fontsize=11)
    fig.tight_layout()
    fig.savefig(out)


if __name__ == "__main__":
    main(Path(__file__).with_name("fixture.png"))
