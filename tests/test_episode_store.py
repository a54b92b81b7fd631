"""Episode store: HDF5 round trip, lazy keyframe reads, store index, corrupt / wrong-version files."""

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from abm.data.episode_store import (  # noqa: E402
    FORMAT_VERSION,
    EpisodeFormatError,
    EpisodeInfo,
    EpisodeStore,
    load_episode,
    save_episode,
)
from abm.types import CameraFrame, Episode, KeyframeAction, Observation  # noqa: E402


def make_episode(task="place_food", split="seen", seed=3, keyframes=3, res=16):
    rng = np.random.default_rng(seed)
    steps = []
    for k in range(keyframes):
        cams = {}
        for name in ("front", "wrist"):
            ext = np.eye(4)
            ext[:3, 3] = rng.normal(size=3)
            cams[name] = CameraFrame(
                rgb=rng.integers(0, 255, (res, res, 3), dtype=np.uint8),
                depth=rng.uniform(0.1, 2.0, (res, res)).astype(np.float32),
                intrinsics=np.array([[20.0, 0, (res - 1) / 2], [0, 20.0, (res - 1) / 2], [0, 0, 1]]),
                extrinsics=ext,
                segmentation=rng.integers(-1, 3, (res, res)).astype(np.int32),
            )
        pose = np.eye(4)
        pose[:3, 3] = [0.4, 0.1 * k, 0.2]
        obs = Observation(cameras=cams, gripper_open=k / keyframes, gripper_pose=pose, step=k)
        act = KeyframeAction(rng.normal(size=3), rng.normal(size=4), bool(k % 2), bool(k == 1))
        steps.append((obs, act))
    return Episode(task=task, variation=2, split=split, instruction="put the ketchup in the plate",
                   object_names={0: "plate", 1: "ketchup", 2: "milk"}, target_names=["ketchup"], steps=steps,
                   success=True, seed=seed, metadata={"resolution": res, "motions": ["reached"] * keyframes})


def test_round_trip_preserves_everything(tmp_path):
    ep = make_episode()
    path = tmp_path / "a" / "ep.h5"
    save_episode(ep, path)
    assert [p.name for p in path.parent.iterdir()] == ["ep.h5"]  # no temporary file left
    back = load_episode(path)
    for field in ("task", "variation", "split", "instruction", "object_names", "target_names", "success",
                  "seed", "metadata"):
        assert getattr(back, field) == getattr(ep, field), field
    assert len(back) == len(ep)
    for (o1, a1), (o2, a2) in zip(ep.steps, back.steps, strict=True):
        assert o1.gripper_open == pytest.approx(o2.gripper_open) and o1.step == o2.step
        assert np.array_equal(o1.gripper_pose, o2.gripper_pose)
        for name in o1.cameras:
            c1, c2 = o1.cameras[name], o2.cameras[name]
            for attr in ("rgb", "depth", "intrinsics", "extrinsics", "segmentation"):
                assert np.array_equal(getattr(c1, attr), getattr(c2, attr)), attr
        assert np.allclose(a1.position, a2.position) and np.allclose(a1.quaternion, a2.quaternion)
        assert (a1.gripper_open, a1.ignore_collision) == (a2.gripper_open, a2.ignore_collision)
    with h5py.File(path) as f:
        assert f["observations/cameras/front/rgb"].compression == "gzip"
        assert f.attrs["format_version"] == FORMAT_VERSION


def test_store_index_select_and_lazy_step(tmp_path):
    save_episode(make_episode("place_food", "seen", 1), tmp_path / "place_food" / "seen" / "e1.h5")
    save_episode(make_episode("pick_block", "unseen", 2, keyframes=2), tmp_path / "pick_block" / "e2.h5")
    save_episode(make_episode("place_food", "unseen", 3), tmp_path / "x" / "y" / "e3.h5")
    store = EpisodeStore(tmp_path)
    assert len(store) == 3
    assert all(isinstance(e, EpisodeInfo) for e in store.episodes)
    by_seed = {e.seed: i for i, e in enumerate(store.episodes)}
    assert store.episodes[by_seed[2]].num_keyframes == 2 and store.episodes[by_seed[2]].task == "pick_block"
    assert sorted(store.select(tasks=["place_food"])) == sorted([by_seed[1], by_seed[3]])
    assert store.select(tasks=["place_food"], splits=["unseen"]) == [by_seed[3]]
    assert store.select(splits=["compositional"]) == []
    assert len(store.select()) == 3
    obs, act = store.load_step(by_seed[1], 2)
    ref_obs, ref_act = make_episode("place_food", "seen", 1).steps[2]
    assert np.array_equal(obs.cameras["wrist"].rgb, ref_obs.cameras["wrist"].rgb)
    assert np.allclose(act.position, ref_act.position)
    assert store.load(by_seed[3]).seed == 3
    with pytest.raises(IndexError):
        store.load_step(by_seed[2], 5)
    assert store.episodes[by_seed[1]].cameras == "front,wrist@16x16"
    store.check_consistent(store.select())
    save_episode(make_episode("place_food", "seen", 4, res=24), tmp_path / "place_food" / "seen" / "e4.h5")
    mixed = EpisodeStore(tmp_path)
    with pytest.raises(EpisodeFormatError, match=r"mixes episodes recorded with different cameras.*24x24"):
        mixed.check_consistent(mixed.select())


def test_corrupt_file_gives_clear_error(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"this is not hdf5")
    with pytest.raises(EpisodeFormatError, match="bad.h5"):
        load_episode(bad)
    with pytest.raises(EpisodeFormatError, match="bad.h5"):
        EpisodeStore(tmp_path)


def test_checksums_catch_bytes_overwritten_inside(tmp_path, capsys):
    from abm.cli import main
    from abm.data.episode_store import verify_episode

    path = tmp_path / "ep.h5"
    save_episode(make_episode(res=32), path)
    assert verify_episode(path) is True
    assert main(["data", "info", str(tmp_path)]) == 0
    assert "checked against its checksum" in capsys.readouterr().out
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle: middle + 4096] = np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    with pytest.raises(EpisodeFormatError, match=r"ep.h5: dataset .* (checksum|cannot be read)"):
        verify_episode(path)
    assert main(["data", "info", str(tmp_path)]) == 2
    assert "corrupt" in capsys.readouterr().err
    assert main(["data", "info", "--quick", str(tmp_path)]) == 0


def test_truncated_file_gives_clear_error(tmp_path):
    path = tmp_path / "ep.h5"
    save_episode(make_episode(), path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(EpisodeFormatError, match="ep.h5"):
        load_episode(path)


def test_wrong_version_and_missing_fields(tmp_path):
    path = tmp_path / "old.h5"
    save_episode(make_episode(), path)
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = FORMAT_VERSION + 1
    with pytest.raises(EpisodeFormatError, match=r"old.h5.*version"):
        load_episode(path)
    with h5py.File(path, "a") as f:  # data from before the label fix is refused with what to do
        f.attrs["format_version"] = FORMAT_VERSION - 1
    with pytest.raises(EpisodeFormatError, match=r"old.h5.*regenerate.*abm data generate"):
        load_episode(path)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(EpisodeFormatError, match=r"other.h5.*format_version"):
        load_episode(other)
    broken = tmp_path / "broken.h5"
    save_episode(make_episode(), broken)
    with h5py.File(broken, "a") as f:
        del f["actions/position"]
    with pytest.raises(EpisodeFormatError, match=r"broken.h5.*keyframe 0"):
        load_episode(broken)


def test_failed_write_leaves_nothing(tmp_path):
    ep = make_episode()
    ep.metadata["bad"] = object()  # not JSON-serialisable
    with pytest.raises(TypeError):
        save_episode(ep, tmp_path / "ep.h5")
    assert list(tmp_path.iterdir()) == []
