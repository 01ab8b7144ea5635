"""The reference rig seen from above (docs/rig.png): the ego's outline, each camera at its place in
the dataset's frame (x forward, y left) with its name, the direction it faces and its horizontal
field of view, the stereo pairs, and the LiDAR. Everything is read from the default ``RigConfig``
(``schemas/rig.py``), so the picture follows the code.

    python tools/make_rig_figure.py --out docs/rig.png
"""

from __future__ import annotations

import argparse
import math

import matplotlib

matplotlib.use("Agg")
from matplotlib import pyplot as plt  # noqa: E402
from matplotlib.patches import Polygon, Rectangle, Wedge  # noqa: E402

from carlaocc.schemas.rig import RigConfig, camera_roles  # noqa: E402

EGO_LENGTH, EGO_WIDTH = 4.8, 2.0  # an outline of a mid-size car around the ego origin, metres


def rig_figure(rig: RigConfig, out: str) -> None:
    fig, ax = plt.subplots(figsize=(7.5, 7.5), dpi=110)
    # the ego: y left is drawn to the left, x forward up the page (plot axes: -y horizontal, x vertical)
    ax.add_patch(Rectangle((-EGO_WIDTH / 2, -EGO_LENGTH / 2), EGO_WIDTH, EGO_LENGTH, fill=False, lw=1.5,
                           ec="0.35", label="ego outline (4.8 x 2.0 m, for scale)"))
    ax.add_patch(Polygon([(-0.35, EGO_LENGTH / 2 - 0.1), (0.35, EGO_LENGTH / 2 - 0.1), (0, EGO_LENGTH / 2 + 0.35)],
                         closed=True, color="0.35"))
    roles = camera_roles(rig.cameras)
    colours = plt.get_cmap("tab10")
    for i, cam in enumerate(rig.cameras):
        x, y, _ = cam.ego_position()
        yaw = cam.ego_yaw_deg
        # the field of view as a wedge: plot angle of the x axis is 90 deg, of the y axis 180 deg
        heading = 90.0 + yaw
        ax.add_patch(Wedge((-y, x), 1.6, heading - cam.hfov_deg / 2, heading + cam.hfov_deg / 2,
                           color=colours(i), alpha=0.18))
        ax.plot([-y], [x], "o", color=colours(i), ms=8, zorder=3,
                label=f"{cam.name}: {roles.get(cam.name, cam.direction)}")
        tip = (-y - 1.1 * math.sin(math.radians(yaw)), x + 1.1 * math.cos(math.radians(yaw)))
        ax.annotate("", xy=tip, xytext=(-y, x), arrowprops={"arrowstyle": "->", "color": colours(i), "lw": 2})
        # the name beyond the arrow's tip; a camera off the ego's axis has it on its own side
        side = 0.0 if abs(y) < 1e-6 or abs(yaw) > 45 and abs(yaw) < 135 else math.copysign(1.0, -y)
        ax.text(tip[0] + 0.55 * (tip[0] + y) / 1.1 + 0.12 * side, tip[1] + 0.55 * (tip[1] - x) / 1.1,
                cam.name.replace("camera_", "cam "), ha={-1.0: "right", 0.0: "center", 1.0: "left"}[side],
                va="center", fontsize=9, color=colours(i), weight="bold")
    lx, ly, lz = rig.lidar.ego_position()
    ax.plot([-ly], [lx], "k*", ms=14, zorder=4, label=f"lidar ({lz:.2f} m up; the frame of the grids)")
    ax.set_xlim(-4.2, 4.2)
    ax.set_ylim(-4.6, 4.6)
    ax.set_aspect("equal")
    ticks = [-4, -2, 0, 2, 4]
    ax.set_xticks(ticks, [f"{-t:g}" for t in ticks])
    ax.set_xlabel("y, m (left +)")
    ax.set_ylabel("x, m (forward +)")
    ax.grid(alpha=0.3)
    ax.set_title(f"The reference rig from above (dataset frame; cameras {rig.cameras[0].hfov_deg:.1f} deg wide)",
                 fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(out, metadata={"Software": None})
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/rig.png")
    rig_figure(RigConfig(), ap.parse_args().out)


if __name__ == "__main__":
    main()
