"""Rendering of one rig: a frame drawn with numpy alone (``rgb_array``), shown with matplotlib
(``human``, imported only then).

The frame shows body 2 (grey) with the pad (green) on top and body 1 (blue) above it, in the
thesis's frame (x down) with lengths magnified so that the reference penetration d_ref spans
``PX_PER_DREF`` pixels, and two bars at the right: the force applied by the shaker (orange, up is
positive) and the contact force (red), both over the scene's command scale.
"""

from __future__ import annotations

import numpy as np

from impact_env.hardware import stage
from impact_env.plant.layout import STATE

WIDTH, HEIGHT = 320, 240
SURFACE_Y = 150  # pixel row of body 2's top surface at x2 = 0
PX_PER_DREF = 20.0
GREY, GREEN, BLUE, ORANGE, RED, BLACK = ((120, 120, 120), (60, 170, 80), (50, 90, 200),
                                         (240, 150, 30), (210, 40, 40), (0, 0, 0))


def _rect(img, x0, x1, y0, y1, colour):
    y0, y1 = sorted((int(round(y0)), int(round(y1))))
    x0, x1 = sorted((int(round(x0)), int(round(x1))))
    y0, y1 = max(y0, 0), min(y1, img.shape[0])
    x0, x1 = max(x0, 0), min(x1, img.shape[1])
    if y1 > y0 and x1 > x0:
        img[y0:y1, x0:x1] = colour


def draw_frame(task, i: int = 0) -> np.ndarray:
    """uint8[HEIGHT, WIDTH, 3] picture of env ``i`` of a :class:`~impact_env.env.task.CatchTask`."""
    sim = task.sim
    y = np.nan_to_num(sim.plant_state[i], nan=0.0)
    px = PX_PER_DREF / task.layout.refs.length
    img = np.full((HEIGHT, WIDTH, 3), 255, dtype=np.uint8)
    top2 = SURFACE_Y + y[STATE.x2] * px
    pad = 8
    _rect(img, 60, 200, top2 + pad, HEIGHT, GREY)
    _rect(img, 60, 200, top2, top2 + pad, GREEN)
    bottom1 = SURFACE_Y + y[STATE.x1] * px
    _rect(img, 100, 160, bottom1 - 50, bottom1, BLUE)
    _rect(img, 0, WIDTH, SURFACE_Y, SURFACE_Y + 1, BLACK)  # rest level of the surface
    mid, half = HEIGHT // 2, HEIGHT // 2 - 10
    scale = task.command_scale
    cols = stage.HW_INFO
    bars = ((240, sim.info[i, cols.f_applied], ORANGE), (280, sim.info[i, cols.contact_force], RED))
    for x, value, colour in bars:
        h = float(np.clip(np.nan_to_num(value) / scale, -1.0, 1.0)) * half
        _rect(img, x, x + 20, mid, mid - h, colour)
        _rect(img, x - 4, x + 24, mid, mid + 1, BLACK)
    return img


def show_frame(frame: np.ndarray, viewer, fps: float):
    """Show a frame in a matplotlib window (``render_mode="human"``); returns the viewer."""
    try:
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - matplotlib is a dependency, but may be stripped
        raise ImportError("render_mode='human' needs matplotlib: pip install matplotlib") from exc
    if viewer is None:
        fig, ax = plt.subplots(figsize=(WIDTH / 80, HEIGHT / 80))
        ax.set_axis_off()
        viewer = (fig, ax.imshow(frame))
        plt.show(block=False)
    else:
        viewer[1].set_data(frame)
    plt.pause(1.0 / fps)
    return viewer


def close_viewer(viewer) -> None:
    import matplotlib.pyplot as plt

    plt.close(viewer[0])
