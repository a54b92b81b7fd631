"""Intel RealSense RGB-D cameras (pyrealsense2) behind the camera interface of :mod:`abm.robot.devices`.

Several cameras, each selected by its serial number, each a :class:`abm.types.CameraFrame` per
:meth:`RealSenseCamera.read`: RGB ``(H, W, 3)`` uint8, depth aligned to the colour image
(``rs.align``) and converted to metres with the device's depth scale, intrinsics ``(3, 3)`` of the
colour stream profile (pixels) and the camera-to-base transform ``(4, 4)`` from the calibration file
(:mod:`abm.robot.calibration`, looked up by camera name, then by serial).

``pyrealsense2`` is imported only when a camera is opened (``pip install pyrealsense2``); tests pass a
fake module as ``rs_module``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from abm.errors import ConfigError, ExternalError
from abm.robot.calibration import load_calibration
from abm.types import CameraFrame

log = logging.getLogger(__name__)


def import_pyrealsense2() -> Any:
    """The ``pyrealsense2`` module, or an :class:`~abm.errors.ExternalError` that says how to install it."""
    try:
        import pyrealsense2
    except ImportError as err:
        raise ExternalError("RealSense cameras need the Intel RealSense SDK's Python bindings: "
                            "pip install pyrealsense2 (see docs/real-robot.md)") from err
    return pyrealsense2


def intrinsics_matrix(intr: Any) -> np.ndarray:
    """``(3, 3)`` pinhole matrix in pixels from an ``rs.intrinsics`` (``fx, fy, ppx, ppy``)."""
    return np.array([[intr.fx, 0.0, intr.ppx], [0.0, intr.fy, intr.ppy], [0.0, 0.0, 1.0]], np.float64)


class RealSenseCamera:
    """One or more RealSense cameras, read together.

    Args:
        serials: serial numbers; a list names each camera by its serial, a mapping ``{name: serial}``
            gives names (e.g. ``{"front": "123622270145"}``).
        calibration: calibration YAML path or its loaded ``{name: {"extrinsics": (4, 4), ...}}``; ``None``
            gives identity extrinsics (only for recording calibration images).
        width / height / fps: colour and depth stream size in pixels and frame rate in Hz.
        timeout_ms: how long :meth:`read` waits for a frame set before failing.
        warmup_frames: frames dropped after start (auto exposure settles).
        rs_module: the ``pyrealsense2`` module (default: imported here).
    """

    def __init__(self, serials: Sequence[str] | Mapping[str, str],
                 calibration: str | Path | Mapping[str, Any] | None = None, width: int = 640, height: int = 480,
                 fps: int = 30, timeout_ms: int = 5000, warmup_frames: int = 15, rs_module: Any = None) -> None:
        rs = rs_module if rs_module is not None else import_pyrealsense2()
        self.rs = rs
        named = dict(serials) if isinstance(serials, Mapping) else {str(s): str(s) for s in serials}
        if not named:
            raise ConfigError("RealSenseCamera needs at least one serial number")
        self.serials = {str(n): str(s) for n, s in named.items()}
        self.names = list(self.serials)
        self.object_names: dict[int, str] = {}  # no segmentation on a real camera
        self.instruction = ""
        self.timeout_ms = int(timeout_ms)
        self.extrinsics = self._extrinsics(calibration)
        connected = [d.get_info(rs.camera_info.serial_number) for d in rs.context().query_devices()]
        missing = [s for s in self.serials.values() if s not in connected]
        if missing:
            raise ExternalError(f"RealSense camera(s) {missing} not connected; connected: {connected or 'none'}")
        self.pipelines: dict[str, Any] = {}
        self.aligners: dict[str, Any] = {}
        self.depth_scale: dict[str, float] = {}
        self.intrinsics: dict[str, np.ndarray] = {}
        try:
            for name, serial in self.serials.items():
                self._start(name, serial, width, height, fps)
            for _ in range(warmup_frames):
                for pipeline in self.pipelines.values():
                    pipeline.wait_for_frames(self.timeout_ms)
        except Exception:
            self.close()
            raise

    def _extrinsics(self, calibration: str | Path | Mapping[str, Any] | None) -> dict[str, np.ndarray]:
        if calibration is None:
            log.warning("RealSenseCamera without a calibration file: extrinsics are the identity (fine for "
                        "recording calibration images, not for running a policy)")
            return {name: np.eye(4) for name in self.serials}
        if isinstance(calibration, (str, Path)):
            calibration = load_calibration(calibration)
        out = {}
        for name, serial in self.serials.items():
            entry = calibration.get(name, calibration.get(serial))
            if entry is None:
                raise ConfigError(f"camera {name!r} (serial {serial}) is not in the calibration file (it has "
                                  f"{sorted(calibration)}); calibrate it with `abm calibrate`")
            out[name] = np.asarray(entry["extrinsics"], np.float64)
        return out

    def _start(self, name: str, serial: str, width: int, height: int, fps: int) -> None:
        rs = self.rs
        config = rs.config()
        config.enable_device(serial)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        pipeline = rs.pipeline()
        profile = pipeline.start(config)
        self.pipelines[name] = pipeline
        self.aligners[name] = rs.align(rs.stream.color)  # depth resampled into the colour image
        self.depth_scale[name] = float(profile.get_device().first_depth_sensor().get_depth_scale())
        colour = profile.get_stream(rs.stream.color).as_video_stream_profile()
        self.intrinsics[name] = intrinsics_matrix(colour.get_intrinsics())
        log.info("RealSense %s (serial %s): %dx%d @ %d Hz, depth scale %.6f m", name, serial, width, height, fps,
                 self.depth_scale[name])

    def read(self) -> dict[str, CameraFrame]:
        """One frame per camera: RGB, depth aligned to colour in metres (0 = no measurement)."""
        out = {}
        for name, pipeline in self.pipelines.items():
            frames = self.aligners[name].process(pipeline.wait_for_frames(self.timeout_ms))
            depth, colour = frames.get_depth_frame(), frames.get_color_frame()
            if not depth or not colour:
                raise ExternalError(f"RealSense {name!r}: incomplete frame set (no depth or no colour)")
            rgb = np.array(np.asanyarray(colour.get_data()), np.uint8)  # copy: the SDK reuses its buffers
            metres = np.asanyarray(depth.get_data()).astype(np.float32) * np.float32(self.depth_scale[name])
            out[name] = CameraFrame(rgb=rgb, depth=metres, intrinsics=self.intrinsics[name],
                                    extrinsics=self.extrinsics[name])
        return out

    def close(self) -> None:
        """Stop every started pipeline (safe to call twice)."""
        for pipeline in self.pipelines.values():
            try:
                pipeline.stop()
            except Exception as err:  # noqa: BLE001 - the SDK raises RuntimeError for a stopped pipeline
                log.debug("RealSense stop: %s", err)
        self.pipelines = {}

    @classmethod
    def from_config(cls, options: Mapping[str, Any], rs_module: Any = None) -> RealSenseCamera:
        """From the robot YAML's ``cameras`` section: ``{kind: realsense, serials: [...] or {name: serial},
        calibration: FILE, width, height, fps, timeout_ms, warmup_frames}``."""
        opts = {k: v for k, v in options.items() if k != "kind"}
        if "serials" not in opts:
            raise ConfigError("cameras: kind realsense needs serials (a list, or {name: serial})")
        allowed = {"serials", "calibration", "width", "height", "fps", "timeout_ms", "warmup_frames"}
        unknown = set(opts) - allowed
        if unknown:
            raise ConfigError(f"cameras: unknown realsense options {sorted(unknown)} (allowed: {sorted(allowed)})")
        serials = opts.pop("serials")
        serials = {str(k): str(v) for k, v in serials.items()} if isinstance(serials, Mapping) else \
            [str(s) for s in serials]
        return cls(serials, rs_module=rs_module, **opts)
