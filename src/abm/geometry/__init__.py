"""Geometry: deprojection, camera fusion, workspace cube, rotations and SE(3) augmentation."""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.geometry.augmentation import augment_cloud, random_se3, transform_action, transform_points
    from abm.geometry.pointcloud import PointCloud, depth_to_points, fuse_cameras, project_to_camera, valid_depth_mask
    from abm.geometry.rotations import (
        DEFAULT_ROTATION_BINS,
        GRIPPER_REFERENCE_YAW_DEG,
        GRIPPER_SYMMETRY,
        ROUND_SYMMETRY,
        bins_to_euler,
        bins_to_quat,
        canonical_gripper_matrix,
        canonical_gripper_quat,
        euler_to_bins,
        euler_to_quat,
        matrix_to_quat,
        normalize_quaternion,
        pose_matrix,
        quat_angle_deg,
        quat_to_bins,
        quat_to_euler,
        quat_to_matrix,
        symmetric_angle_deg,
    )
    from abm.geometry.workspace import Workspace

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = [
    "DEFAULT_ROTATION_BINS", "GRIPPER_REFERENCE_YAW_DEG", "GRIPPER_SYMMETRY", "ROUND_SYMMETRY",
    "canonical_gripper_matrix", "canonical_gripper_quat", "symmetric_angle_deg", "PointCloud", "Workspace",
    "augment_cloud", "bins_to_euler", "bins_to_quat",
    "depth_to_points", "euler_to_bins", "euler_to_quat", "fuse_cameras", "matrix_to_quat",
    "normalize_quaternion", "pose_matrix", "project_to_camera", "quat_angle_deg", "quat_to_bins",
    "quat_to_euler", "quat_to_matrix", "random_se3", "transform_action", "transform_points",
    "valid_depth_mask",
]
