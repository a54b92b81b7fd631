"""Camera calibration into the robot base frame: the calibration file and hand-eye calibration with a
ChArUco board held by the gripper (OpenCV).

**Calibration file** (YAML)::

    cameras:
      front:                       # camera name or serial number
        intrinsics: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
        extrinsics: [[...4 x 4 camera-to-base transform, metres...]]

**Hand-eye (eye-to-hand).** The camera is fixed; the board is fixed to the gripper at an unknown offset.
The arm shows the board to the camera in several poses; for each, the board's pose in the camera comes
from the detected ChArUco corners (``solvePnP``) and the gripper's pose in the base frame from the arm.
:func:`hand_eye_fixed_camera` then solves for the camera-to-base transform and the board's offset.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from abm.errors import ConfigError, DataError
from abm.files import load_yaml, write_text_atomic
from abm.robot.devices import ReplayCamera

if TYPE_CHECKING:  # OpenCV (the `robot` extra) is imported where it is used
    import cv2


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares`` ``(x, y)``, square and marker sides in metres, ArUco dictionary name."""

    squares: tuple[int, int] = (5, 7)
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: str = "DICT_4X4_50"

    def board(self) -> cv2.aruco.CharucoBoard:
        import cv2

        if not hasattr(cv2.aruco, self.dictionary):
            raise ConfigError(f"unknown ArUco dictionary {self.dictionary!r}")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, dictionary)

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m


def board_pose(image: np.ndarray, intrinsics: np.ndarray, spec: BoardSpec, min_corners: int = 6
               ) -> tuple[np.ndarray, float] | None:
    """The board's pose in the camera ``(4, 4)`` (board-to-camera) and the RMS reprojection error in pixels,
    or ``None`` when fewer than ``min_corners`` ChArUco corners are found."""
    import cv2

    board = spec.board()
    gray = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if corners is None or ids is None or len(ids) < min_corners:
        return None
    obj = np.asarray(board.getChessboardCorners())[ids.reshape(-1)].astype(np.float64)
    img = corners.reshape(-1, 2).astype(np.float64)
    k = np.asarray(intrinsics, np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, None)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = tvec.reshape(3)
    return pose, rms


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(m)
    rotation: np.ndarray = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return rotation


def hand_eye_fixed_camera(gripper_poses: Sequence[np.ndarray], board_poses: Sequence[np.ndarray]) -> np.ndarray:
    """Camera-to-base ``(4, 4)`` from pairs of gripper-to-base ``A_i`` and board-to-camera ``B_i`` poses.

    Solves ``A_i Y = X B_i`` for the camera-to-base ``X`` and the unknown board-to-gripper ``Y`` (the
    robot-world / hand-eye problem): rotations in closed form (null space of the stacked Kronecker
    equations, projected onto SO(3)), translations by linear least squares, then a joint refinement of
    both poses with ``scipy.optimize.least_squares``. Needs at least 3 pairs with rotations about
    different axes. (Written here because OpenCV 5's Python bindings no longer expose ``calibrateHandEye``.)
    """
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    if len(gripper_poses) != len(board_poses) or len(gripper_poses) < 3:
        raise ValueError(f"hand-eye calibration needs at least 3 pose pairs, got {len(gripper_poses)} and "
                         f"{len(board_poses)}")
    a = [np.asarray(g, np.float64) for g in gripper_poses]
    b = [np.asarray(p, np.float64) for p in board_poses]
    eye = np.eye(3)
    # R_A R_Y = R_X R_B  ->  (I kron R_A) vec(R_Y) - (R_B^T kron I) vec(R_X) = 0   (column-major vec)
    rows = np.vstack([np.hstack([np.kron(eye, ai[:3, :3]), -np.kron(bi[:3, :3].T, eye)])
                      for ai, bi in zip(a, b, strict=True)])
    v = np.linalg.svd(rows)[2][-1]
    r_y, r_x = v[:9].reshape(3, 3, order="F"), v[9:].reshape(3, 3, order="F")
    scale = np.cbrt(np.linalg.det(r_x))
    r_x, r_y = _nearest_rotation(r_x / scale), _nearest_rotation(r_y / scale)
    # R_A t_Y + t_A = R_X t_B + t_X  ->  [R_A, -I] [t_Y; t_X] = R_X t_B - t_A
    lhs = np.vstack([np.hstack([ai[:3, :3], -eye]) for ai in a])
    rhs = np.concatenate([r_x @ bi[:3, 3] - ai[:3, 3] for ai, bi in zip(a, b, strict=True)])
    t = np.linalg.lstsq(lhs, rhs, rcond=None)[0]

    def unpack(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, y = np.eye(4), np.eye(4)
        x[:3, :3], x[:3, 3] = Rotation.from_rotvec(z[:3]).as_matrix(), z[3:6]
        y[:3, :3], y[:3, 3] = Rotation.from_rotvec(z[6:9]).as_matrix(), z[9:]
        return x, y

    def residuals(z: np.ndarray) -> np.ndarray:
        x, y = unpack(z)
        return np.concatenate([((ai @ y) - (x @ bi))[:3].ravel() for ai, bi in zip(a, b, strict=True)])

    start = np.concatenate([Rotation.from_matrix(r_x).as_rotvec(), t[3:], Rotation.from_matrix(r_y).as_rotvec(), t[:3]])
    return unpack(least_squares(residuals, start).x)[0]


def save_calibration(path: str | Path, cameras: Mapping[str, Mapping[str, np.ndarray]]) -> Path:
    """Write the calibration file (``{name: {"intrinsics": (3, 3), "extrinsics": (4, 4)}}``)."""
    import yaml

    data = {"cameras": {str(n): {k: np.asarray(v, float).round(9).tolist() for k, v in c.items()}
                        for n, c in cameras.items()}}
    path = Path(path)
    write_text_atomic(path, yaml.safe_dump(data, sort_keys=True))
    return path


def load_calibration(path: str | Path) -> dict[str, dict[str, np.ndarray]]:
    """Read and check a calibration file; ``ValueError`` names the camera and the problem."""
    data = load_yaml(path, "calibration file") or {}
    cameras = data.get("cameras") if isinstance(data, dict) else None
    if not isinstance(cameras, dict) or not cameras:
        raise ConfigError(f"{path}: no 'cameras' section")
    out = {}
    for name, cam in cameras.items():
        try:
            k = np.asarray(cam["intrinsics"], np.float64)
            t = np.asarray(cam["extrinsics"], np.float64)
        except (KeyError, TypeError, ValueError) as err:
            raise ConfigError(f"{path}: camera {name!r} needs intrinsics (3 x 3) and extrinsics (4 x 4): "
                              f"{err}") from None
        if k.shape != (3, 3) or t.shape != (4, 4):
            raise ConfigError(f"{path}: camera {name!r}: intrinsics {k.shape}, extrinsics {t.shape}; "
                              "expected (3, 3), (4, 4)")
        if not (np.all(np.isfinite(k)) and np.all(np.isfinite(t))):
            raise ConfigError(f"{path}: camera {name!r}: intrinsics and extrinsics must be finite numbers (no .nan "
                              "or .inf)")
        unknown = sorted(str(key) for key in cam if key not in ("intrinsics", "extrinsics"))
        if unknown:
            raise ConfigError(f"{path}: camera {name!r}: unknown keys {unknown} (expected: extrinsics, intrinsics)")
        if not np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-5) or not np.allclose(t[3], [0, 0, 0, 1]):
            raise ConfigError(f"{path}: camera {name!r}: extrinsics is not a rigid transform")
        out[str(name)] = {"intrinsics": k, "extrinsics": t}
    return out


def render_board_image(spec: BoardSpec, intrinsics: np.ndarray, board_to_camera: np.ndarray,
                       size: tuple[int, int] = (640, 480), px_per_m: float = 4000.0) -> np.ndarray:
    """A synthetic ``(H, W, 3)`` uint8 camera image of the board at a known pose (white background), for
    testing calibration against ground truth."""
    import cv2

    w_m, h_m = spec.size_m
    board_img = spec.board().generateImage((int(round(w_m * px_per_m)), int(round(h_m * px_per_m))), marginSize=0)
    pose = np.asarray(board_to_camera, np.float64)
    plane = np.column_stack([pose[:3, 0], pose[:3, 1], pose[:3, 3]])  # board (x, y, 1) -> camera
    homography = np.asarray(intrinsics, np.float64) @ plane @ np.diag([1 / px_per_m, 1 / px_per_m, 1.0])
    gray = cv2.warpPerspective(board_img, homography, size, flags=cv2.INTER_AREA, borderValue=255)
    return np.repeat(gray[:, :, None], 3, axis=2)


def calibrate_from_recording(folder: str | Path, camera: str, spec: BoardSpec | None = None
                             ) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Hand-eye calibration of ``camera`` from a recording (``abm.robot.record_observations``) in which the
    arm showed the gripper-mounted board in several poses.

    Returns:
        ``(intrinsics, camera-to-base, stats)``; stats: views used, mean reprojection error (pixels).
    """
    spec = spec or BoardSpec()
    replay = ReplayCamera(folder)
    if camera not in replay.names:
        raise ConfigError(f"camera {camera!r} is not in the recording (it has {replay.names})")
    grippers, boards, errors, intrinsics = [], [], [], None
    for k in range(replay.steps):
        frame = replay.read()[camera]
        intrinsics = frame.intrinsics
        found = board_pose(frame.rgb, frame.intrinsics, spec)
        if found is None:
            continue
        grippers.append(replay._load(k)["gripper_pose"])
        boards.append(found[0])
        errors.append(found[1])
    if len(boards) < 3:
        raise DataError(f"the board was found in {len(boards)} of {replay.steps} images; hand-eye calibration "
                        "needs at least 3 (show the whole board, from different angles)")
    assert intrinsics is not None  # every image read sets it, and at least 3 were
    return intrinsics, hand_eye_fixed_camera(grippers, boards), {"views": len(boards),
                                                                 "reprojection_px": float(np.mean(errors))}
