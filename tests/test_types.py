"""Validation of the data contracts: wrong shapes, dtypes and values name the offending field."""

import numpy as np
import pytest

from abm.types import CameraFrame, Episode, KeyframeAction, Observation


def frame(h: int = 4, w: int = 5) -> CameraFrame:
    k = np.array([[10.0, 0, (w - 1) / 2], [0, 10.0, (h - 1) / 2], [0, 0, 1]])
    return CameraFrame(np.zeros((h, w, 3), np.uint8), np.ones((h, w), np.float32), k, np.eye(4))


def test_valid_frame_and_observation():
    f = frame()
    assert (f.height, f.width) == (4, 5)
    obs = Observation({"front": f}, gripper_open=1.0)
    assert obs.camera("front") is f


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"rgb": np.zeros((4, 5), np.uint8)}, "CameraFrame.rgb"),
        ({"rgb": np.zeros((4, 5, 3), np.float32)}, "CameraFrame.rgb"),
        ({"depth": np.ones((4, 6), np.float32)}, "CameraFrame.depth"),
        ({"depth": np.ones((4, 5), np.int32)}, "CameraFrame.depth"),
        ({"intrinsics": np.eye(4)}, "CameraFrame.intrinsics"),
        ({"extrinsics": np.eye(3)}, "CameraFrame.extrinsics"),
        ({"extrinsics": np.diag([1.0, 1.0, -1.0, 1.0])}, "CameraFrame.extrinsics"),
        ({"segmentation": np.zeros((4, 5), np.float32)}, "CameraFrame.segmentation"),
    ],
)
def test_frame_rejects_bad_fields(kwargs, field):
    f = frame()
    args = {"rgb": f.rgb, "depth": f.depth, "intrinsics": f.intrinsics, "extrinsics": f.extrinsics}
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        CameraFrame(**args)


def test_observation_errors():
    with pytest.raises(ValueError, match="cameras"):
        Observation({}, gripper_open=1.0)
    with pytest.raises(ValueError, match="gripper_open"):
        Observation({"front": frame()}, gripper_open=2.0)
    with pytest.raises(KeyError, match="available: \\['front'\\]"):
        Observation({"front": frame()}, gripper_open=1.0).camera("wrist")


def test_action_normalises_quaternion_and_rejects_bad_values():
    a = KeyframeAction([0.1, 0.2, 0.3], [0, 0, 0, 2.0], gripper_open=1, ignore_collision=0)
    np.testing.assert_allclose(a.quaternion, [0, 0, 0, 1])
    assert a.gripper_open is True and a.ignore_collision is False
    np.testing.assert_allclose(a.matrix[:3, 3], [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="KeyframeAction.quaternion"):
        KeyframeAction([0, 0, 0], [0, 0, 0, 0], True)
    with pytest.raises(ValueError, match="KeyframeAction.position"):
        KeyframeAction([0, 0], [0, 0, 0, 1], True)


def test_episode_validation():
    obs = Observation({"front": frame()}, gripper_open=1.0)
    act = KeyframeAction([0, 0, 0], [0, 0, 0, 1], True)
    ep = Episode("pick_block", 0, "seen", "put the red block on the target", {0: "red block"}, ["red block"],
                 [(obs, act)], success=True)
    assert len(ep) == 1
    with pytest.raises(ValueError, match="split"):
        Episode("t", 0, "train", "x", {}, [], [], False)
    with pytest.raises(ValueError, match="target_names"):
        Episode("t", 0, "seen", "x", {0: "red block"}, ["blue block"], [], False)
    with pytest.raises(ValueError, match=r"steps\[0\]"):
        Episode("t", 0, "seen", "x", {}, [], [(obs,)], False)
