"""Draw the conventions' figure (docs/img/frames.png): ROCASPECT's base frame F_b, masts,
exit points A_ij, the platform frame F_p and anchors B_ij, and one cable's vectors.

    python docs/tools/frames_figure.py docs/img/frames.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from controller.pose import rotation  # noqa: E402
from controller.robot import resolve_robot  # noqa: E402

POSE = np.array([10.0, 8.56, 1.2, 0.0, 0.0, 0.3])  # a platform pose to draw [m, rad]


def _top(ax, robot, B) -> None:
    """Top view: footprint, masts, exit points, cables, F_b and F_p."""
    A = robot.exits
    for k, cid in enumerate(robot.cable_ids):
        ax.plot([A[k, 0], B[k, 0]], [A[k, 1], B[k, 1]], color="0.6", lw=0.8)
        out = np.sign(A[k, :2] - [10.0, 8.5])  # outward from the footprint's centre
        ax.annotate(f"A{cid}", A[k, :2], textcoords="offset points", fontsize=8,
                    xytext=(8 * out[0] - (22 if out[0] < 0 else 0), 8 * out[1] - 4))
    ax.scatter(A[:, 0], A[:, 1], s=14, color="tab:red", zorder=3, label="exit points A_ij")
    ax.scatter(robot.pivots[:, 0], robot.pivots[:, 1], marker="s", s=30, color="k", zorder=3,
               label="mast pivots O_i")
    for i, mid in enumerate(robot.mast_ids):
        ax.annotate(f"mast {mid}", robot.pivots[i, :2], textcoords="offset points",
                    xytext=(12 if robot.pivots[i, 0] < 10 else -48,
                            14 if robot.pivots[i, 1] < 8 else -18), fontsize=8)
    ax.fill(*_platform_outline(POSE).T, color="tab:blue", alpha=0.3, label="platform")
    _axes2d(ax, np.zeros(2), np.eye(2), 2.5, "F_b")
    R = rotation(POSE[3:])
    _axes2d(ax, POSE[:2], R[:2, :2], 1.5, "F_p")
    ax.set_xlabel("x_b [m]")
    ax.set_ylabel("y_b [m]")
    ax.set_title("top view (z_b up, out of the page)")
    ax.set_aspect("equal")
    ax.set_xlim(-3, 23)
    ax.set_ylim(-2.5, 19.5)
    ax.grid(alpha=0.3)
    ax.legend(loc="center right", fontsize=8)


def _platform_outline(pose: np.ndarray) -> np.ndarray:
    R = rotation(pose[3:])
    c = np.array([[0.5, 0.5, 0], [-0.5, 0.5, 0], [-0.5, -0.5, 0], [0.5, -0.5, 0]])
    return (pose[:3] + c @ R.T)[:, :2]


def _axes2d(ax, origin, R2, size, label) -> None:
    for k, (name, col) in enumerate((("x", "tab:red"), ("y", "tab:green"))):
        d = R2[:, k] * size
        ax.annotate("", origin + d, origin, arrowprops=dict(arrowstyle="->", color=col, lw=1.5))
        ax.text(*(origin + d * 1.12), f"{name}", color=col, fontsize=8)
    ax.text(origin[0] + 0.3, origin[1] - 1.2, label, fontsize=9, weight="bold")


def _cable(ax, robot, B, k: int = 2) -> None:
    """Side view of one cable (ij = robot.cable_ids[k]): O_i, A_ij, B_ij, l_ij, u_ij,
    gravity, the platform frame."""
    cid = robot.cable_ids[k]
    i = robot.mast_index[k]
    pivot, A = robot.pivots[i], robot.exits[k]
    t = POSE[:3]
    # draw in the vertical plane through the exit point and the platform centre
    h = (t - A)[:2] / np.linalg.norm((t - A)[:2])

    def p(v):
        return np.array([np.dot(v[:2] - A[:2], h), v[2]])

    ax.plot(*np.c_[p(pivot), p(A)], color="k", lw=4, solid_capstyle="butt", label=f"mast {i + 1}")
    ax.plot(*np.c_[p(A), p(B[k])], color="0.4", lw=1.2, label=f"cable {cid}")
    ax.plot(*np.c_[p(A), p(A) + np.array([0, -1.2])], color="0.4", lw=1.2, ls=":")
    ax.text(*(p(A) + [0.15, -1.0]), "to the winch (v_ij)", fontsize=8)
    for name, v, off in (("O_i (pivot)", pivot, (0.2, 0.1)), ("A_ij (exit point)", A, (0.2, 0.15)),
                         ("B_ij (anchor)", B[k], (0.2, -0.35)), ("F_p origin t", t, (0.2, 0.2))):
        ax.scatter(*p(v), color="tab:red" if "A" in name else "k", s=18, zorder=3)
        ax.text(*(p(v) + off), name, fontsize=8)
    u = (A - B[k]) / np.linalg.norm(A - B[k])
    ax.annotate("", p(B[k]) + 2.0 * np.array([np.dot(u[:2], h), u[2]]), p(B[k]),
                arrowprops=dict(arrowstyle="->", color="tab:orange", lw=2))
    ax.text(*(p(B[k]) + [-2.2, 1.0]), "u_ij = l_ij / d_ij", color="tab:orange", fontsize=8)
    ax.text(*(0.5 * (p(A) + p(B[k])) + [0.2, 0.2]), "l_ij = a_ij - t - R b_ij\n"
            "(length d_ij)", fontsize=8, color="0.3")
    ax.annotate("", p(t) + [0, -1.2], p(t), arrowprops=dict(arrowstyle="->", color="tab:blue"))
    ax.text(*(p(t) + [0.15, -1.1]), "m g", color="tab:blue", fontsize=8)
    ax.fill(*np.c_[p(t) + [-0.5, -0.25], p(t) + [0.5, -0.25], p(t) + [0.5, 0.25],
                   p(t) + [-0.5, 0.25]], color="tab:blue", alpha=0.3)
    ax.axhline(0, color="0.5", lw=1)
    ax.set_xlabel(f"horizontal distance from A{cid} towards the platform [m]")
    ax.set_ylabel("z_b [m]")
    ax.set_title(f"one cable, side view (cable {cid})")
    ax.set_aspect("equal")
    ax.set_ylim(-0.5, 4.6)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


def draw(out: Path) -> None:
    robot = resolve_robot("rocaspect")
    R = rotation(POSE[3:])
    B = POSE[:3] + robot.anchors @ R.T
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(14, 6.2), gridspec_kw={"width_ratios": [1, 1.25]})
    _top(a1, robot, B)
    _cable(a2, robot, B)
    fig.suptitle("Frames and names: F_b (base, z up), F_p (platform), cable ij = cable j of "
                 "mast i; pose (x, y, z, roll, pitch, yaw), R = Rz(yaw) Ry(pitch) Rx(roll)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    draw(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/img/frames.png"))
