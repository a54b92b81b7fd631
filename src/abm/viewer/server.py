"""Draw a :class:`~abm.viewer.record.ViewerRecord` in the browser with viser (served locally, works offline).

The page shows the fused point cloud (coloured by RGB or by mask-field score, with a threshold slider),
the target's points, the workspace cube, the five virtual cameras with their rendered views, the
expert's (green) and the predicted (orange) keyframes as gripper frames, and a step slider (the
timeline). The side panel repeats the five views at full size.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from abm.errors import ConfigError, ExternalError
from abm.grounding.visualize import colormap, upscale
from abm.viewer.record import EXPERT_COLOR, PREDICTED_COLOR, ViewerRecord, ViewerStep, view_camera_pose

# Where each keyframe's label hangs from its frame's origin (m, world frame): the expert's above, the
# prediction's below, so the two never overlap when the prediction lands on or near the expert.
LABEL_OFFSETS: dict[str, np.ndarray] = {"expert": np.array([0.0, 0.0, 0.05]),
                                        "predicted": np.array([0.0, 0.0, -0.05])}

COLOR_MODES = ("rgb", "mask score")
VIEW_PIXELS = 200  # views are enlarged (nearest neighbour) to at least this side for display


def cube_edges(center: np.ndarray, size: float) -> np.ndarray:
    """The 12 edges of an axis-aligned cube: ``(12, 2, 3)`` segment end points (metres)."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    corners = np.asarray(center, np.float64) + corners * size / 2.0
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    return np.stack([corners[[i, j]] for i, j in edges]).astype(np.float32)


def point_colors(step: ViewerStep, mode: str, threshold: float) -> np.ndarray:
    """``(N, 3)`` uint8 colours of the cloud: its RGB, or its mask-field score through the colour map with the
    points under ``threshold`` greyed out (``mask score`` mode)."""
    if mode == "rgb" or step.scores is None:
        return step.colors
    colors = colormap(step.scores)
    grey = (step.colors.astype(np.float32).mean(1, keepdims=True) * 0.5 + 60).astype(np.uint8)
    return np.where((step.scores >= threshold)[:, None], colors, np.repeat(grey, 3, 1))


def _enlarge(image: np.ndarray) -> np.ndarray:
    return upscale(image, max(1, -(-VIEW_PIXELS // image.shape[0])))


def _wxyz(matrix: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    return np.array([w, x, y, z])


class ViewerServer:
    """A viser server showing one :class:`ViewerRecord`; :meth:`show` switches the step."""

    def __init__(self, record: ViewerRecord, host: str = "127.0.0.1", port: int = 8080) -> None:
        try:
            import viser
        except ImportError as err:  # pragma: no cover - viser is a core dependency
            raise ExternalError("abm view needs viser: pip install viser") from err
        if not record.steps:
            raise ValueError("the record has no steps to show")
        self.record = record
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.url = f"http://{host}:{self.server.get_port()}"
        ws = record.workspace
        center = np.asarray(ws.center, np.float64)
        server = self.server
        server.scene.set_up_direction("+z")
        server.initial_camera.position = tuple(center + np.array([-1.3, -1.1, 1.5]) * ws.size)
        server.initial_camera.look_at = tuple(center)
        server.scene.add_line_segments("/workspace", cube_edges(center, ws.size), colors=(90, 90, 90),
                                       thickness=0.003)

        gui = server.gui
        gui.add_markdown(f"**{record.instruction}**  \n{record.title}"
                         + (f"  \ntarget: *{record.target_name}*" if record.target_name else ""))
        # Positions count from 1; the episode's own keyframe index (0 = the start) is shown beside the slider.
        self.step_slider = gui.add_slider("step", 1, max(len(record.steps), 2), 1, 1,
                                          disabled=len(record.steps) == 1)
        self.step_text = gui.add_markdown("")
        self.color_mode = gui.add_dropdown("colour", COLOR_MODES, initial_value="rgb")
        self.threshold = gui.add_slider("score threshold", 0.0, 1.0, 0.01, 0.5)
        self.point_size = gui.add_slider("point size (mm)", 1.0, 12.0, 0.5, 4.0)
        self.show_target = gui.add_checkbox("highlight target points", True)
        self.view_images: list[Any] = []
        with gui.add_folder("virtual views (mask cyan, heatmap jet)"):
            for name, image in zip(record.view_names, record.steps[0].views, strict=True):
                self.view_images.append(gui.add_image(_enlarge(image), label=name))
        self.frustums: list[Any] = []
        # Each virtual camera is drawn half a cube outside the face it looks through, its picture a quarter
        # cube outside that face (viser draws the image at depth scale / tan(fov / 2) from the apex).
        half_height, depth = 0.175 * ws.size, 0.25 * ws.size
        for name, image in zip(record.view_names, record.steps[0].views, strict=True):
            position, wxyz = view_camera_pose(ws, name, distance=0.5 * ws.size)
            self.frustums.append(server.scene.add_camera_frustum(
                f"/views/{name}", fov=2.0 * float(np.arctan(half_height / depth)), aspect=1.0, scale=half_height,
                thickness=2.0, thickness_units="screen", image=_enlarge(image), wxyz=wxyz, position=position,
                color=(90, 90, 210)))
        for handle in (self.step_slider, self.color_mode, self.threshold, self.point_size, self.show_target):
            handle.on_update(lambda _event: self.show(int(self.step_slider.value) - 1))
        self.show(0)

    def show(self, index: int) -> None:
        """Draw step ``index`` (an index into ``record.steps``, from 0)."""
        step = self.record.steps[index]
        self.step_text.content = step_caption(step.index, index, len(self.record.steps))
        scene = self.server.scene
        size = float(self.point_size.value) / 1000.0
        scene.add_point_cloud("/cloud", points=step.points,
                              colors=point_colors(step, str(self.color_mode.value), float(self.threshold.value)),
                              point_size=size)
        if step.target is not None and self.show_target.value and step.target.any():
            scene.add_point_cloud("/target", points=step.points[step.target], colors=(255, 0, 200),
                                  point_size=size * 1.6)
        else:
            scene.add_point_cloud("/target", points=np.zeros((0, 3), np.float32), colors=(255, 0, 200),
                                  point_size=size)
        scene.add_frame("/gripper", axes_length=0.04, axes_radius=0.002, position=step.gripper_pose[:3, 3],
                        wxyz=_wxyz(step.gripper_pose))
        for key, action, color in (("expert", step.expert, EXPERT_COLOR), ("predicted", step.predicted,
                                                                              PREDICTED_COLOR)):
            if action is None:
                continue
            scene.add_frame(f"/{key}", axes_length=0.07, axes_radius=0.004, origin_radius=0.012,
                            origin_color=color, position=action.position, wxyz=_wxyz(action.matrix))
            # The two labels hang from their frames on opposite sides, so they never cover each other when the
            # predicted keyframe lands on (or near) the expert's.
            scene.add_label(f"/labels/{key}", f"{key} {'open' if action.gripper_open else 'closed'}",
                            position=tuple(np.asarray(action.position, np.float64) + LABEL_OFFSETS[key]))
        for image_handle, frustum, image in zip(self.view_images, self.frustums, step.views, strict=True):
            image_handle.image = frustum.image = _enlarge(image)

    def close(self) -> None:
        """Stop the server."""
        self.server.stop()


def step_caption(keyframe: int, position: int, count: int) -> str:
    """The text beside the step slider: the episode's keyframe index (0 is the start) and the position shown.

    ``position`` counts from 0 in the record's steps, ``count`` is their number.
    """
    start = " (start)" if keyframe == 0 else ""
    return f"keyframe {keyframe}{start} — step {position + 1} of {count}"


def check_port(host: str, port: int) -> None:
    """Raise :class:`~abm.errors.ConfigError` (one line, with the fix) unless the server can listen on ``host:port``."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
    except (OSError, OverflowError) as err:
        reason = getattr(err, "strerror", None) or str(err)
        raise ConfigError(f"cannot serve on {host}:{port} ({reason}); choose another --port (e.g. {port % 65535 + 1}) "
                          "or --host, or stop the program that uses it") from None


def serve(record: ViewerRecord, host: str = "127.0.0.1", port: int = 8080) -> ViewerServer:
    """Start serving ``record`` (returns at once; the server runs in background threads).

    Raises:
        ValueError: the address is busy or invalid (checked before any thread starts).
    """
    check_port(host, port)
    return ViewerServer(record, host, port)
