"""Data contracts shared by every part of abm.

Conventions (used everywhere in the package):

* Lengths are metres, angles radians unless a name says ``_deg``.
* The world frame is the robot-base frame: origin at the base of the arm, +x forward
  (towards the table), +y to the robot's left, +z up.
* Cameras follow the OpenCV convention: +x right, +y down, +z forward (the viewing
  direction). ``extrinsics`` are **camera-to-world** 4x4 homogeneous transforms, so a
  point ``p_cam`` seen by the camera is at ``extrinsics @ [p_cam, 1]`` in the world.
* Quaternions are scalar-last ``(x, y, z, w)``, as in :class:`scipy.spatial.transform.Rotation`.

Every dataclass validates itself on construction and raises :class:`ValueError` with the
offending field named, so bad data is caught where it enters rather than deep inside a model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from abm.configuration import SPLITS  # noqa: F401 - the object splits, re-exported beside Split

Split = Literal["seen", "unseen", "compositional"]


def _check_array(
    name: str,
    value: object,
    shape: tuple[int | None, ...],
    dtypes: tuple[type, ...] | None = None,
) -> np.ndarray:
    """Return ``value`` as an ndarray after checking its shape (``None`` = any size) and dtype."""
    if not isinstance(value, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(value).__name__}")
    if value.ndim != len(shape) or any(s is not None and s != v for s, v in zip(shape, value.shape, strict=True)):
        want = "x".join("N" if s is None else str(s) for s in shape)
        raise ValueError(f"{name} must have shape {want}, got {tuple(value.shape)}")
    if dtypes is not None and not any(np.issubdtype(value.dtype, d) for d in dtypes):
        names = " or ".join(d.__name__ for d in dtypes)
        raise ValueError(f"{name} must have dtype {names}, got {value.dtype}")
    return value


def _check_rigid(name: str, value: np.ndarray, atol: float = 1e-4) -> None:
    """Check that a 4x4 matrix is a rigid transform (orthonormal rotation, last row 0 0 0 1)."""
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{name} contains non-finite values")
    if not np.allclose(value[3], [0.0, 0.0, 0.0, 1.0], atol=atol):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {value[3].tolist()}")
    rot = value[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) or np.linalg.det(rot) < 0:
        raise ValueError(f"{name} must contain a proper rotation (orthonormal, det +1)")


@dataclass
class CameraFrame:
    """One calibrated RGB-D image.

    Attributes:
        rgb: ``uint8`` array ``(H, W, 3)``.
        depth: ``float32`` array ``(H, W)``: distance along the camera +z axis in metres;
            0, NaN or inf mark pixels without a measurement.
        intrinsics: ``(3, 3)`` pinhole matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels,
            OpenCV convention: the centre of pixel ``(row, col)`` is at image coordinates
            ``(u, v) = (col, row)``, so a centred principal point is ``((W - 1) / 2, (H - 1) / 2)``.
        extrinsics: ``(4, 4)`` camera-to-world transform (OpenCV camera axes).
        segmentation: optional ``int32`` ``(H, W)`` object ids (simulation only; -1 = none).
    """

    rgb: NDArray[np.uint8]
    depth: NDArray[np.floating]
    intrinsics: NDArray[np.float64]
    extrinsics: NDArray[np.float64]
    segmentation: NDArray[np.integer] | None = None

    def __post_init__(self) -> None:
        _check_array("CameraFrame.rgb", self.rgb, (None, None, 3), (np.uint8,))
        h, w = self.rgb.shape[:2]
        _check_array("CameraFrame.depth", self.depth, (h, w), (np.floating,))
        self.intrinsics = np.asarray(_check_array("CameraFrame.intrinsics", self.intrinsics, (3, 3)), np.float64)
        self.extrinsics = np.asarray(_check_array("CameraFrame.extrinsics", self.extrinsics, (4, 4)), np.float64)
        _check_rigid("CameraFrame.extrinsics", self.extrinsics)
        fx, fy = self.intrinsics[0, 0], self.intrinsics[1, 1]
        if not (np.isfinite(fx) and np.isfinite(fy) and fx > 0 and fy > 0):
            raise ValueError(f"CameraFrame.intrinsics must have positive focal lengths, got fx={fx}, fy={fy}")
        if self.segmentation is not None:
            _check_array("CameraFrame.segmentation", self.segmentation, (h, w), (np.integer,))

    @property
    def height(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[1])


@dataclass
class Observation:
    """Everything the robot perceives at one (keyframe) time step.

    Attributes:
        cameras: camera name (e.g. ``"front"``, ``"wrist"``) -> :class:`CameraFrame`.
        gripper_open: opening state in ``[0, 1]`` (1 = fully open).
        gripper_pose: ``(4, 4)`` gripper-to-world transform of the tool centre point.
        step: time step index of this observation within its episode.
    """

    cameras: dict[str, CameraFrame]
    gripper_open: float
    gripper_pose: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    step: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.cameras, dict) or not self.cameras:
            raise ValueError("Observation.cameras must be a non-empty dict of name -> CameraFrame")
        for name, frame in self.cameras.items():
            if not isinstance(frame, CameraFrame):
                raise ValueError(f"Observation.cameras[{name!r}] must be a CameraFrame, got {type(frame).__name__}")
        if not 0.0 <= float(self.gripper_open) <= 1.0:
            raise ValueError(f"Observation.gripper_open must be in [0, 1], got {self.gripper_open}")
        self.gripper_open = float(self.gripper_open)
        self.gripper_pose = np.asarray(self.gripper_pose, np.float64)
        _check_array("Observation.gripper_pose", self.gripper_pose, (4, 4))
        _check_rigid("Observation.gripper_pose", self.gripper_pose)

    def camera(self, name: str) -> CameraFrame:
        """Return one camera, with an error listing the available ones when it is missing."""
        try:
            return self.cameras[name]
        except KeyError:
            raise KeyError(f"camera {name!r} not in observation; available: {sorted(self.cameras)}") from None


@dataclass
class KeyframeAction:
    """The next gripper keyframe the policy asks for.

    Attributes:
        position: ``(3,)`` tool-centre-point target in the world frame, metres.
        quaternion: ``(4,)`` target orientation, ``(x, y, z, w)``; normalised on construction.
        gripper_open: whether the gripper should be open at the keyframe.
        ignore_collision: whether the motion may move in a straight line ignoring collisions.
        kind: what the keyframe does in a demonstration (``"approach"``, ``"grasp"``, ``"lift"``,
            ``"move"``, ``"place"``, ``"retreat"``, ``"pour"``, ...); empty for policy outputs.
        symmetry: how many turns about the gripper (TCP z) axis give the same keyframe: 2 for the
            parallel gripper alone (180 degrees), 4 for a square object handled from above, 0 for a
            round one (any turn). Demonstration labels are stored in the canonical member of this class
            (:func:`abm.geometry.canonical_gripper_quat`).
    """

    position: NDArray[np.float64]
    quaternion: NDArray[np.float64]
    gripper_open: bool
    ignore_collision: bool = False
    kind: str = ""
    symmetry: int = 2

    def __post_init__(self) -> None:
        self.position = np.asarray(self.position, np.float64)
        self.quaternion = np.asarray(self.quaternion, np.float64)
        _check_array("KeyframeAction.position", self.position, (3,))
        _check_array("KeyframeAction.quaternion", self.quaternion, (4,))
        if not np.all(np.isfinite(self.position)):
            raise ValueError("KeyframeAction.position contains non-finite values")
        norm = float(np.linalg.norm(self.quaternion))
        if not np.isfinite(norm) or norm < 1e-6:
            raise ValueError("KeyframeAction.quaternion must be a non-zero finite quaternion (x, y, z, w)")
        self.quaternion = self.quaternion / norm
        self.gripper_open = bool(self.gripper_open)
        self.ignore_collision = bool(self.ignore_collision)
        self.kind = str(self.kind)
        self.symmetry = int(self.symmetry)
        if self.symmetry < 0:
            raise ValueError(f"KeyframeAction.symmetry must be >= 0 (0 = any turn), got {self.symmetry}")

    @property
    def matrix(self) -> NDArray[np.float64]:
        """``(4, 4)`` gripper-to-world transform of the target."""
        from scipy.spatial.transform import Rotation

        out = np.eye(4)
        out[:3, :3] = Rotation.from_quat(self.quaternion).as_matrix()
        out[:3, 3] = self.position
        return out


@dataclass
class Trajectory:
    """The full motion of an episode sampled at a fixed control rate (``abm data generate --dense``).

    Attributes:
        fps: frames per second (the control rate of the recording).
        observations: ``T`` observations, frame ``t`` taken at ``t / fps`` seconds after the episode start.
        joint_positions: ``(T, 9)`` measured arm (7) and finger (2) joint positions, rad / m.
        joint_actions: ``(T, 8)`` the command after frame ``t``: 7 arm joint servo targets (rad) and the
            gripper command (1 = open, 0 = close), as in effect at the next control tick.
        ee_actions: ``(T, 8)`` the same command as an end-effector target: the TCP position (3, m) and
            orientation ``(x, y, z, w)`` (4) reached at frame ``t + 1`` and the gripper command.
        keyframe_frames: ``(K,)`` index of the frame each keyframe observation is (one per episode step).
    """

    fps: float
    observations: list[Observation]
    joint_positions: NDArray[np.float64]
    joint_actions: NDArray[np.float64]
    ee_actions: NDArray[np.float64]
    keyframe_frames: NDArray[np.int64]

    def __post_init__(self) -> None:
        n = len(self.observations)
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"Trajectory.fps must be positive, got {self.fps}")
        if n == 0 or not all(isinstance(o, Observation) for o in self.observations):
            raise ValueError("Trajectory.observations must be a non-empty list of Observation")
        self.joint_positions = np.asarray(self.joint_positions, np.float64)
        self.joint_actions = np.asarray(self.joint_actions, np.float64)
        self.ee_actions = np.asarray(self.ee_actions, np.float64)
        self.keyframe_frames = np.asarray(self.keyframe_frames, np.int64)
        _check_array("Trajectory.joint_positions", self.joint_positions, (n, 9))
        _check_array("Trajectory.joint_actions", self.joint_actions, (n, 8))
        _check_array("Trajectory.ee_actions", self.ee_actions, (n, 8))
        _check_array("Trajectory.keyframe_frames", self.keyframe_frames, (None,))
        if len(self.keyframe_frames) and (self.keyframe_frames.min() < 0 or self.keyframe_frames.max() >= n
                                          or np.any(np.diff(self.keyframe_frames) < 0)):
            raise ValueError(f"Trajectory.keyframe_frames must be non-decreasing frame indices in [0, {n})")

    def __len__(self) -> int:
        return len(self.observations)


@dataclass
class Episode:
    """One demonstration or rollout, stored at keyframes.

    Attributes:
        task: task name, e.g. ``"place_food"``.
        variation: index of the instruction/scene variation within the task.
        split: ``"seen"``, ``"unseen"`` or ``"compositional"``.
        instruction: the full English instruction.
        object_names: segmentation id -> canonical object name for every object in the scene.
        target_names: canonical names of the object(s) the instruction refers to.
        steps: ``(observation, action)`` pairs: the action is the keyframe to reach from that observation.
        success: whether the episode ended in success.
        seed: the scene seed the episode was generated from (``-1`` if unknown).
        metadata: free-form extra information (simulator version, timings, ...).
        trajectory: the dense recording at a fixed control rate, when one was made (``--dense``); its
            ``keyframe_frames`` has one entry per step.
    """

    task: str
    variation: int
    split: str
    instruction: str
    object_names: dict[int, str]
    target_names: list[str]
    steps: list[tuple[Observation, KeyframeAction]]
    success: bool
    seed: int = -1
    metadata: dict[str, Any] = field(default_factory=dict)
    trajectory: Trajectory | None = None

    def __post_init__(self) -> None:
        if self.trajectory is not None and len(self.trajectory.keyframe_frames) != len(self.steps):
            raise ValueError(f"Episode.trajectory marks {len(self.trajectory.keyframe_frames)} keyframes, "
                             f"the episode has {len(self.steps)} steps")
        if self.split not in SPLITS:
            raise ValueError(f"Episode.split must be one of {SPLITS}, got {self.split!r}")
        if not self.instruction.strip():
            raise ValueError("Episode.instruction must not be empty")
        for i, step in enumerate(self.steps):
            if not (isinstance(step, tuple) and len(step) == 2):
                raise ValueError(f"Episode.steps[{i}] must be an (Observation, KeyframeAction) pair")
            obs, act = step
            if not isinstance(obs, Observation) or not isinstance(act, KeyframeAction):
                raise ValueError(f"Episode.steps[{i}] must be an (Observation, KeyframeAction) pair")
        missing = [n for n in self.target_names if n not in self.object_names.values()]
        if missing:
            raise ValueError(f"Episode.target_names {missing} are not among the scene objects")

    def __len__(self) -> int:
        return len(self.steps)


#: Version of the simulated objects and expert labels of each ABM-Bench task changed since its first version,
#: with what changed (every other task is at version 1). Episodes recorded in simulation store the version they
#: were made with as ``metadata["task_version"]`` (none stored = 1); :mod:`abm.data.episode_store` refuses
#: those of an older version, since they show other objects or teach other labels than the task now has.
TASK_DATA_VERSIONS: dict[str, tuple[int, str]] = {
    "close_jar": (2, "the lid's 1.6 cm knob, one pixel of the policy's views, became a 6.4 cm bar handle that "
                     "the grasp yaw follows"),
    "water_plants": (2, "containers stand with their handle across the grasp, which is labelled with one fixed "
                        "yaw instead of the handle's, too small for the policy's views to show"),
}
#: Episode metadata key of the task version an episode was recorded with (see :data:`TASK_DATA_VERSIONS`).
TASK_VERSION_KEY = "task_version"


def task_data_version(task: str) -> int:
    """The current version of ``task``'s simulated objects and expert labels (1 unless it changed since)."""
    return TASK_DATA_VERSIONS[task][0] if task in TASK_DATA_VERSIONS else 1
