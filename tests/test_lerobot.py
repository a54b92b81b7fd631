"""LeRobot v3 export / import: the schema on disk, round trips of keyframe-only and dense episodes through
the real CLI, and the errors for bad input."""

import json

import numpy as np
import pytest

pytest.importorskip("h5py")
pytest.importorskip("av")
pq = pytest.importorskip("pyarrow.parquet")

from abm.cli import main  # noqa: E402
from abm.data.episode_store import load_episode, save_episode  # noqa: E402
from abm.types import CameraFrame, Episode, KeyframeAction, Observation, Trajectory  # noqa: E402

RES = 16
RGB_TOL = 12  # max mean absolute difference (0-255) of an H.264 (crf 18) frame of smooth test images


def _frame(rng, t: float) -> CameraFrame:
    yy, xx = np.mgrid[0:RES, 0:RES]
    rgb = np.stack([(xx * 12 + 40 * t) % 256, (yy * 12) % 256, np.full_like(xx, 90 + int(50 * t))], -1)
    ext = np.eye(4)
    ext[:3, 3] = [0.5, 0.1 * t, 1.0]
    return CameraFrame(rgb=rgb.astype(np.uint8), depth=rng.uniform(0.2, 2.0, (RES, RES)).astype(np.float32),
                       intrinsics=np.array([[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]]), extrinsics=ext,
                       segmentation=rng.integers(-1, 3, (RES, RES)).astype(np.int32))


def _obs(rng, t: float, step: int) -> Observation:
    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.05 * t, 0.3]
    return Observation(cameras={"front": _frame(rng, t), "wrist": _frame(rng, t + 0.5)},
                       gripper_open=float(np.float32(1 - t / 4)), gripper_pose=pose, step=step)


def make_episode(seed: int, keyframes: int = 3, dense: bool = False) -> Episode:
    rng = np.random.default_rng(seed)
    actions = [KeyframeAction(rng.normal(size=3), rng.normal(size=4), bool(k % 2), k == 1,
                              ["approach", "grasp", "lift"][k % 3], [2, 4, 0][k % 3]) for k in range(keyframes)]
    trajectory = None
    if dense:
        frames = np.array([0, 3, 7][:keyframes])
        n = 9
        obs = [_obs(rng, i / n, int(np.searchsorted(frames, i, side="right") - 1)) for i in range(n)]
        steps = [(obs[f], a) for f, a in zip(frames, actions, strict=True)]
        trajectory = Trajectory(fps=10.0, observations=obs, joint_positions=rng.normal(size=(n, 9)),
                                joint_actions=rng.normal(size=(n, 8)), ee_actions=rng.normal(size=(n, 8)),
                                keyframe_frames=frames)
    else:
        steps = [(_obs(rng, k / keyframes, k), a) for k, a in enumerate(actions)]
    meta = {"resolution": RES, "motions": ["reached"] * keyframes} | ({"dense_fps": 10.0} if dense else {})
    return Episode(task="pick_block", variation=1, split="seen", instruction=f"pick up the block {seed}",
                   object_names={0: "red block", 1: "plate", 2: "milk"}, target_names=["red block"], steps=steps,
                   success=True, seed=seed, metadata=meta, trajectory=trajectory)


def _store(tmp_path, dense: bool, seeds=(0, 1)):
    data = tmp_path / "data"
    eps = {}
    for s in seeds:
        ep = make_episode(s, dense=dense)
        save_episode(ep, data / "pick_block" / "seen" / f"episode_{s:06d}.h5")
        eps[s] = ep
    return data, eps


def _assert_same_observation(a: Observation, b: Observation) -> None:
    assert a.step == b.step and a.gripper_open == b.gripper_open
    assert np.array_equal(a.gripper_pose, b.gripper_pose)
    for name, ca in a.cameras.items():
        cb = b.cameras[name]
        for attr in ("depth", "segmentation", "intrinsics", "extrinsics"):
            assert np.array_equal(getattr(ca, attr), getattr(cb, attr)), attr
        assert np.abs(ca.rgb.astype(int) - cb.rgb.astype(int)).mean() < RGB_TOL


def _assert_same_episode(a: Episode, b: Episode) -> None:
    for field in ("task", "variation", "split", "instruction", "object_names", "target_names", "success", "seed",
                  "metadata"):
        assert getattr(a, field) == getattr(b, field), field
    assert len(a.steps) == len(b.steps)
    for (oa, aa), (ob, ab) in zip(a.steps, b.steps, strict=True):
        _assert_same_observation(oa, ob)
        assert np.array_equal(aa.position, ab.position)
        assert np.allclose(aa.quaternion, ab.quaternion, rtol=0, atol=1e-15)  # re-normalised on load: last bit
        assert (aa.gripper_open, aa.ignore_collision, aa.kind, aa.symmetry) == \
            (ab.gripper_open, ab.ignore_collision, ab.kind, ab.symmetry)


def test_keyframe_export_schema_and_round_trip(tmp_path, capsys):
    data, eps = _store(tmp_path, dense=False)
    ds = tmp_path / "ds"
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 0
    info = json.loads((ds / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 1.0
    assert info["total_episodes"] == 2 and info["total_frames"] == 6 and info["total_tasks"] == 2
    feats = info["features"]
    assert feats["observation.images.front"]["dtype"] == "video"
    assert feats["observation.images.front"]["shape"] == [RES, RES, 3]
    assert feats["observation.depth.wrist"] == {**feats["observation.depth.wrist"], "dtype": "float32",
                                                "shape": [RES, RES]}
    data_table = pq.read_table(ds / "data/chunk-000/file-000.parquet")
    non_video = {k for k, f in feats.items() if f["dtype"] != "video"}
    assert set(data_table.column_names) == non_video
    ts = data_table.column("timestamp").to_numpy()
    fi = data_table.column("frame_index").to_numpy()
    assert np.allclose(ts, fi / info["fps"])
    assert data_table.column("keyframe.is_keyframe").to_pylist() == [True] * 6
    tasks = pq.read_table(ds / "meta" / "tasks.parquet").to_pylist()
    assert sorted(t["task"] for t in tasks) == ["pick up the block 0", "pick up the block 1"]
    episodes = pq.read_table(ds / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e["dataset_from_index"], e["dataset_to_index"], e["length"]) for e in episodes] == [(0, 3, 3), (3, 6, 3)]
    assert episodes[1]["videos/observation.images.front/from_timestamp"] == 3.0
    assert episodes[0]["tasks"] == ["pick up the block 0"]
    assert (ds / "videos/observation.images.wrist/chunk-000/file-000.mp4").stat().st_size > 0
    stats = json.loads((ds / "meta" / "stats.json").read_text())
    assert len(stats["observation.images.front"]["mean"]) == 3 and len(stats["action"]["mean"]) == 8

    back = tmp_path / "back"
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(back)]) == 0
    for s, ep in eps.items():
        again = load_episode(back / "pick_block" / "seen" / f"episode_{s:06d}.h5")
        _assert_same_episode(ep, again)
        assert again.trajectory is None
    assert "2 episodes" in capsys.readouterr().out


def test_dense_export_round_trip(tmp_path):
    data, eps = _store(tmp_path, dense=True, seeds=(4,))
    ds = tmp_path / "ds"
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 0
    info = json.loads((ds / "meta" / "info.json").read_text())
    assert info["fps"] == 10.0 and info["total_frames"] == 9 and info["abm"]["frames"] == "dense"
    table = pq.read_table(ds / "data/chunk-000/file-000.parquet")
    assert np.flatnonzero(table.column("keyframe.is_keyframe").to_numpy(zero_copy_only=False)).tolist() == [0, 3, 7]
    assert table.column("keyframe.index").to_pylist() == [0, 0, 0, 1, 1, 1, 1, 2, 2]
    assert np.allclose(table.column("timestamp").to_numpy(), np.arange(9) / 10.0)
    back = tmp_path / "back"
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(back)]) == 0
    ep, again = eps[4], load_episode(back / "pick_block" / "seen" / "episode_000004.h5")
    _assert_same_episode(ep, again)
    t0, t1 = ep.trajectory, again.trajectory
    assert t1 is not None and t1.fps == t0.fps and np.array_equal(t1.keyframe_frames, t0.keyframe_frames)
    assert np.array_equal(t1.joint_positions, t0.joint_positions)
    assert np.allclose(t1.joint_actions, t0.joint_actions, atol=1e-6)  # float32 in the dataset
    assert np.allclose(t1.ee_actions, t0.ee_actions, atol=1e-6)
    for a, b in zip(t0.observations, t1.observations, strict=True):
        _assert_same_observation(a, b)
    # keyframes-only export of the same dense store: one frame per keyframe
    ds2 = tmp_path / "ds2"
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds2),
                 "--frames", "keyframes"]) == 0
    assert json.loads((ds2 / "meta" / "info.json").read_text())["total_frames"] == 3


def test_bad_inputs_give_clear_errors(tmp_path, capsys):
    ds = tmp_path / "ds"
    assert main(["data", "export", "--format", "lerobot", "--data", str(tmp_path / "nope"), "--out", str(ds)]) == 2
    assert "not a folder of abm episodes" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["data", "export", "--format", "lerobot", "--data", str(tmp_path / "empty"), "--out", str(ds)]) == 2
    assert "no abm episodes" in capsys.readouterr().err
    assert not ds.exists()
    data, _ = _store(tmp_path, dense=False, seeds=(0,))
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds),
                 "--frames", "dense"]) == 2
    assert "has no dense trajectory" in capsys.readouterr().err
    assert not ds.exists()  # the partial export was removed

    assert main(["data", "import", "--format", "lerobot", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
    (tmp_path / "notds").mkdir()
    assert main(["data", "import", "--format", "lerobot", str(tmp_path / "notds"), "--out", str(tmp_path / "o")]) == 2
    assert "not a LeRobot dataset" in capsys.readouterr().err

    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 0
    info_path = ds / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info_path.write_text("{not json")
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(tmp_path / "o")]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    info_path.write_text(json.dumps({**info, "codebase_version": "v2.1"}))
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(tmp_path / "o")]) == 2
    assert "version 'v2.1'" in capsys.readouterr().err
    info_path.write_text(json.dumps({k: v for k, v in info.items() if k != "abm"}))
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(tmp_path / "o")]) == 2
    assert "no abm section" in capsys.readouterr().err
    info_path.write_text(json.dumps(info))
    (ds / "data/chunk-000/file-000.parquet").write_bytes(b"garbage")
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(tmp_path / "o")]) == 2
    assert "does not match the checksum the export recorded" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before anything was written
    # exporting into a non-empty folder is refused
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 2
    assert "not an empty folder" in capsys.readouterr().err
    assert info_path.exists()  # and the existing dataset is left alone


def test_the_export_loads_with_lerobots_parquet_loader(tmp_path):
    """LeRobot 0.4 reads the frames with Hugging Face ``datasets`` (features mapped from info.json: shape (1,)
    -> Value, 1-D -> Sequence, 2-D -> Array2D) and the tasks with pandas (task string as the index). The
    lerobot package itself is not installed here (it pulls torchvision); this runs where datasets and
    pandas are installed and is skipped elsewhere."""
    datasets = pytest.importorskip("datasets")
    pd = pytest.importorskip("pandas")
    data, eps = _store(tmp_path, dense=True, seeds=(2,))
    ds = tmp_path / "ds"
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 0
    info = json.loads((ds / "meta" / "info.json").read_text())
    feats = {}
    for key, ft in info["features"].items():
        shape = tuple(ft["shape"])
        if ft["dtype"] == "video":
            continue
        feats[key] = (datasets.Value(ft["dtype"]) if shape == (1,) else
                      datasets.Sequence(length=shape[0], feature=datasets.Value(ft["dtype"])) if len(shape) == 1
                      else datasets.Array2D(shape=shape, dtype=ft["dtype"]))
    parquet = ds / info["data_path"].format(chunk_index=0, file_index=0)
    frames = datasets.load_dataset("parquet", data_files=str(parquet), features=datasets.Features(feats), split="train",
                                   cache_dir=str(tmp_path / "hf"))
    assert frames.num_rows == info["total_frames"] == 9
    row = frames.with_format("numpy")[3]
    traj = eps[2].trajectory
    assert np.array_equal(row["observation.depth.front"], traj.observations[3].cameras["front"].depth)
    assert bool(row["keyframe.is_keyframe"]) and row["keyframe.kind"] == "grasp"
    tasks = pd.read_parquet(ds / "meta" / "tasks.parquet")
    assert tasks.index.name == "task" and tasks.loc["pick up the block 2", "task_index"] == 0


@pytest.mark.parametrize("argv, words", [
    (["data", "export"], ["LeRobot v3.0", "--frames", "--crf"]),
    (["data", "import"], ["LeRobot v3.0", "--out"]),
    (["data", "generate"], ["--dense", "--dense-fps", "--backend", "--ray-address"]),
    (["eval"], ["--backend", "--ray-address"]),
])
def test_new_options_have_help(argv, words, capsys):
    with pytest.raises(SystemExit) as done:
        main([*argv, "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert all(w in text for w in words), [w for w in words if w not in text]
