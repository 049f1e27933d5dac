"""Draw the factor graph of the joint refinement (docs/figures/joint_graph.png).

    python docs/figures/joint_graph.py

Circles are variables (the shared sensor pose T, the track states x_{j,k}, the per-track
lateral offsets b_j and, dashed, the optional side bias beta of ``joint.side_bias_sigma``);
small squares are factors: priors on T, b_j and x_{j,0}, process between consecutive states,
contour measurement on each state, semantic point-to-point between T, each state, its track's
offset b_j (and beta).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLOURS = {
    "prior": "#7f7f7f",
    "process": "#1f77b4",
    "measurement": "#2ca02c",
    "semantic p2p": "#d62728",
}


def factor(ax, xy: tuple[float, float], kind: str, ends: list[tuple[float, float]]) -> None:
    for e in ends:
        ax.plot([xy[0], e[0]], [xy[1], e[1]], color=COLOURS[kind], lw=1.0, zorder=1)
    ax.add_patch(plt.Rectangle((xy[0] - 0.09, xy[1] - 0.09), 0.18, 0.18,
                               color=COLOURS[kind], zorder=3))


def variable(ax, xy: tuple[float, float], text: str, big: bool = False,
             optional: bool = False) -> None:
    ax.add_patch(plt.Circle(xy, 0.5 if big else 0.38, facecolor="white", edgecolor="black",
                            lw=1.5, ls="--" if optional else "-", zorder=2))
    ax.text(*xy, text, ha="center", va="center", fontsize=10 if big else 8, zorder=4)


def draw(path: Path) -> None:
    fig, ax = plt.subplots(figsize=(9, 5.2))
    T = (3.5, 0.0)
    beta = (6.6, 0.0)
    factor(ax, (2.3, 0.0), "prior", [T])
    tracks = {1: (3.2, 4), 2: (-3.2, 3)}  # track j: (row y, number of steps)
    for j, (y, n) in tracks.items():
        xs = [1.0 + 1.6 * k for k in range(n)]
        pts = [(x, y) for x in xs]
        b = (-0.6, y * 0.45)
        factor(ax, (xs[0] - 0.8, y), "prior", [pts[0]])
        factor(ax, (b[0] - 0.75, b[1]), "prior", [b])
        for k in range(n):
            up = 1.0 if y > 0 else -1.0
            factor(ax, (xs[k], y + 0.9 * up), "measurement", [pts[k]])
            mid = ((xs[k] + T[0]) / 2, (y + T[1]) / 2)
            ax.plot([mid[0], beta[0]], [mid[1], beta[1]], color=COLOURS["semantic p2p"],
                    lw=0.7, ls="--", zorder=1)
            factor(ax, mid, "semantic p2p", [pts[k], T, b])
            if k + 1 < n:
                factor(ax, (xs[k] + 0.8, y), "process", [pts[k], pts[k + 1]])
        for k, p in enumerate(pts):
            variable(ax, p, f"x$_{{{j},{k}}}$")
        variable(ax, b, f"b$_{j}$")
    variable(ax, T, "T", big=True)
    variable(ax, beta, "β", optional=True)
    for kind, c in COLOURS.items():
        ax.plot([], [], "s", color=c, label=f"{kind} factor")
    ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False, fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlim(-1.9, 7.5)
    ax.set_ylim(-5.0, 5.0)
    ax.axis("off")
    ax.set_title("joint refinement: shared sensor pose T, track states x$_{j,k}$, "
                 "offsets b$_j$, optional side bias β (dashed)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    draw(Path(__file__).with_name("joint_graph.png"))
