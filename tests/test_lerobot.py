"""LeRobot v3 export / import: the schema on disk (what LeRobot's policies read, keyframe exports marked as such,
per-episode stats, files split at the announced size), round trips of keyframe-only and dense episodes through
the real CLI, exports of the first format, datasets written by other tools, and the errors for bad input."""

import io
import json

import numpy as np
import pytest

pytest.importorskip("h5py")
av = pytest.importorskip("av")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from abm.cli import main  # noqa: E402
from abm.data.episode_store import load_episode, save_episode  # noqa: E402
from abm.data.lerobot_foreign import detect_keyframes  # noqa: E402
from abm.data.lerobot_schema import format1_key  # noqa: E402
from abm.files import sha256_file  # noqa: E402
from abm.types import CameraFrame, Episode, KeyframeAction, Observation, Trajectory  # noqa: E402

RES = 16
RGB_TOL = 12  # max mean absolute difference (0-255) of an H.264 (crf 18) frame of smooth test images
MIB = 1024 * 1024


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


def _export(data, ds, *extra) -> dict:
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds), *extra]) == 0
    return json.loads((ds / "meta" / "info.json").read_text())


def _import(ds, out, *extra) -> int:
    return main(["data", "import", "--format", "lerobot", str(ds), "--out", str(out), *extra])


def _assert_same_observation(a: Observation, b: Observation, rgb_exact: bool = False) -> None:
    assert a.step == b.step and a.gripper_open == b.gripper_open
    assert np.array_equal(a.gripper_pose, b.gripper_pose)
    for name, ca in a.cameras.items():
        cb = b.cameras[name]
        for attr in ("depth", "segmentation", "intrinsics", "extrinsics"):
            assert np.array_equal(getattr(ca, attr), getattr(cb, attr)), attr
        if rgb_exact:
            assert np.array_equal(ca.rgb, cb.rgb)
        else:
            assert np.abs(ca.rgb.astype(int) - cb.rgb.astype(int)).mean() < RGB_TOL


def _assert_same_episode(a: Episode, b: Episode, rgb_exact: bool = False) -> None:
    for field in ("task", "variation", "split", "instruction", "object_names", "target_names", "success", "seed",
                  "metadata"):
        assert getattr(a, field) == getattr(b, field), field
    assert len(a.steps) == len(b.steps)
    for (oa, aa), (ob, ab) in zip(a.steps, b.steps, strict=True):
        _assert_same_observation(oa, ob, rgb_exact)
        assert np.array_equal(aa.position, ab.position)
        assert np.allclose(aa.quaternion, ab.quaternion, rtol=0, atol=1e-15)  # re-normalised on load: last bit
        assert (aa.gripper_open, aa.ignore_collision, aa.kind, aa.symmetry) == \
            (ab.gripper_open, ab.ignore_collision, ab.kind, ab.symmetry)


def lerobot_policy_features(features: dict) -> dict[str, str]:
    """The feature types LeRobot gives a policy: the rules of ``lerobot.datasets.utils.dataset_to_policy_features``
    (lerobot 0.4), restated here since lerobot cannot be installed: cameras by dtype, ``observation.environment_state``
    exactly, then any key starting with ``observation`` is STATE and any starting with ``action`` is ACTION;
    everything else is left out."""
    types = {}
    for key, ft in features.items():
        if ft["dtype"] in ("image", "video"):
            types[key] = "VISUAL"
        elif key == "observation.environment_state":
            types[key] = "ENV"
        elif key.startswith("observation"):
            types[key] = "STATE"
        elif key.startswith("action"):
            types[key] = "ACTION"
    return types


def _data_files(ds) -> list:
    return sorted((ds / "data").glob("chunk-*/file-*.parquet"))


def _episode_table(ds) -> list[dict]:
    return pq.read_table(ds / "meta/episodes/chunk-000/file-000.parquet").to_pylist()


def test_keyframe_export_schema_and_round_trip(tmp_path, capsys):
    data, eps = _store(tmp_path, dense=False)
    ds = tmp_path / "ds"
    info = _export(data, ds)
    # marked as keyframes, not as a frame rate: fps is LeRobot's index step, timestamps are not invented
    assert info["codebase_version"] == "v3.0" and info["frame_sampling"] == "keyframes" and info["fps"] == 1
    assert info["abm"]["format"] == 2 and info["abm"]["frames"] == "keyframes" and info["video_path"] is None
    assert info["total_episodes"] == 2 and info["total_frames"] == 6 and info["total_tasks"] == 2
    feats = info["features"]
    assert feats["observation.images.front"] == {"dtype": "image", "shape": [RES, RES, 3],
                                                 "names": ["height", "width", "channels"]}
    assert feats["geometry.depth.wrist"]["dtype"] == "float32" and feats["geometry.depth.wrist"]["shape"] == [RES, RES]
    assert lerobot_policy_features(feats) == {"observation.images.front": "VISUAL",
                                              "observation.images.wrist": "VISUAL", "observation.state": "STATE",
                                              "action": "ACTION"}
    assert not (ds / "videos").exists()
    data_table = pq.read_table(ds / "data/chunk-000/file-000.parquet")
    assert set(data_table.column_names) == set(feats)  # images are parquet columns too
    assert np.isnan(data_table.column("timestamp").to_numpy()).all()  # keyframe-only episodes kept no time
    assert data_table.column("keyframe.is_keyframe").to_pylist() == [True] * 6
    tasks = pq.read_table(ds / "meta" / "tasks.parquet").to_pylist()
    assert sorted(t["task"] for t in tasks) == ["pick up the block 0", "pick up the block 1"]
    episodes = _episode_table(ds)
    assert [(e["dataset_from_index"], e["dataset_to_index"], e["length"]) for e in episodes] == [(0, 3, 3), (3, 6, 3)]
    assert episodes[0]["tasks"] == ["pick up the block 0"]
    # per-episode stats as LeRobot v3 writes them (stats/<feature>/<stat>), pooled into stats.json
    state = np.stack(data_table.column("observation.state").to_pylist())
    for e in episodes:
        mine = state[e["dataset_from_index"]:e["dataset_to_index"]]
        assert np.allclose(e["stats/observation.state/mean"], mine.mean(0))
        assert np.allclose(e["stats/observation.state/max"], mine.max(0)) and e["stats/observation.state/count"] == [3]
        assert np.array(e["stats/observation.images.front/mean"]).shape == (3, 1, 1)
        assert "stats/timestamp/mean" not in e  # no stats of unknown values
    stats = json.loads((ds / "meta" / "stats.json").read_text())
    assert np.allclose(stats["observation.state"]["mean"], state.mean(0))
    assert np.allclose(stats["observation.state"]["std"], state.std(0))
    assert stats["observation.state"]["count"] == [6] and np.array(stats["observation.images.front"]["mean"]).shape \
        == (3, 1, 1)

    back = tmp_path / "back"
    assert _import(ds, back) == 0
    for s, ep in eps.items():
        again = load_episode(back / "pick_block" / "seen" / f"episode_{s:06d}.h5")
        _assert_same_episode(ep, again, rgb_exact=True)  # PNG: the images come back exactly
        assert again.trajectory is None
    assert "2 episodes" in capsys.readouterr().out


def test_dense_export_round_trip(tmp_path):
    data, eps = _store(tmp_path, dense=True, seeds=(4, 5))
    ds = tmp_path / "ds"
    info = _export(data, ds)
    assert info["fps"] == 10 and info["frame_sampling"] == "fixed_rate" and info["abm"]["frames"] == "dense"
    assert info["total_frames"] == 18 and info["features"]["observation.images.front"]["dtype"] == "video"
    assert lerobot_policy_features(info["features"]) == {
        "observation.images.front": "VISUAL", "observation.images.wrist": "VISUAL", "observation.state": "STATE",
        "action": "ACTION"}  # depth, calibration, joints and the end-effector action are not read as state
    table = pq.read_table(ds / "data/chunk-000/file-000.parquet")
    assert np.flatnonzero(table.column("keyframe.is_keyframe").to_numpy(zero_copy_only=False)[:9]).tolist() == [0, 3, 7]
    assert table.column("keyframe.index").to_pylist()[:9] == [0, 0, 0, 1, 1, 1, 1, 2, 2]
    assert np.allclose(table.column("timestamp").to_numpy(), np.tile(np.arange(9) / 10.0, 2))
    episodes = _episode_table(ds)
    assert [e["videos/observation.images.front/from_timestamp"] for e in episodes] == [0.0, 0.9]
    assert [e["videos/observation.images.front/to_timestamp"] for e in episodes] == [0.9, 1.8]
    assert sorted(info["abm"]["sha256"]) == sorted([
        "data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet", "meta/tasks.parquet",
        "videos/observation.images.front/chunk-000/file-000.mp4",
        "videos/observation.images.wrist/chunk-000/file-000.mp4"])
    back = tmp_path / "back"
    assert _import(ds, back) == 0
    for seed in (4, 5):
        ep, again = eps[seed], load_episode(back / "pick_block" / "seen" / f"episode_{seed:06d}.h5")
        _assert_same_episode(ep, again)
        t0, t1 = ep.trajectory, again.trajectory
        assert t1 is not None and t1.fps == t0.fps and np.array_equal(t1.keyframe_frames, t0.keyframe_frames)
        assert np.array_equal(t1.joint_positions, t0.joint_positions)
        assert np.allclose(t1.joint_actions, t0.joint_actions, atol=1e-6)  # float32 in the dataset
        assert np.allclose(t1.ee_actions, t0.ee_actions, atol=1e-6)
        for a, b in zip(t0.observations, t1.observations, strict=True):
            _assert_same_observation(a, b)
    # keyframes of the same dense store: one frame per keyframe, at the time it was recorded
    ds2 = tmp_path / "ds2"
    info2 = _export(data, ds2, "--frames", "keyframes")
    assert info2["total_frames"] == 6 and info2["frame_sampling"] == "keyframes"
    times = pq.read_table(ds2 / "data/chunk-000/file-000.parquet").column("timestamp").to_numpy()
    assert np.allclose(times, np.tile([0.0, 0.3, 0.7], 2))
    back2 = tmp_path / "back2"
    assert _import(ds2, back2) == 0
    again = load_episode(back2 / "pick_block" / "seen" / "episode_000004.h5")
    assert again.trajectory is None
    for (oa, _), (ob, _) in zip(eps[4].steps, again.steps, strict=True):
        _assert_same_observation(oa, ob, rgb_exact=True)


def test_a_store_mixing_dense_and_keyframe_episodes_exports_keyframes_saying_so(tmp_path, capsys):
    data, _ = _store(tmp_path, dense=True, seeds=(1,))
    save_episode(make_episode(2), data / "pick_block" / "seen" / "episode_000002.h5")
    info = _export(data, tmp_path / "ds")
    assert info["frame_sampling"] == "keyframes"
    assert "some episodes have no dense trajectory (e.g. " in capsys.readouterr().err  # abm's log lines: stderr
    times = pq.read_table(tmp_path / "ds/data/chunk-000/file-000.parquet").column("timestamp").to_numpy()
    assert np.allclose(times[:3], [0.0, 0.3, 0.7]) and np.isnan(times[3:]).all()  # recorded times, or none


def _row_group_bytes(path) -> int:
    """A parquet file's size without its footer (the metadata; its length is in the last 8 bytes)."""
    raw = path.read_bytes()
    return len(raw) - int.from_bytes(raw[-8:-4], "little") - 8


def test_files_are_split_at_the_announced_size(tmp_path):
    data, eps = _store(tmp_path, dense=True, seeds=(0, 1, 2, 3))
    # a limit below one episode: every episode in files of its own (an episode is never split)
    ds = tmp_path / "ds"
    info = _export(data, ds, "--data-file-mb", "0.001", "--video-file-mb", "0.001")
    assert info["data_files_size_in_mb"] == 0.001 and info["video_files_size_in_mb"] == 0.001
    assert [p.relative_to(ds).as_posix() for p in _data_files(ds)] == [
        f"data/chunk-000/file-{i:03d}.parquet" for i in range(4)]
    episodes = _episode_table(ds)
    assert [(e["data/file_index"], e["videos/observation.images.wrist/file_index"],
             e["videos/observation.images.wrist/from_timestamp"]) for e in episodes] == [(i, i, 0.0) for i in range(4)]
    for e in episodes:
        rows = pq.read_table(ds / f"data/chunk-000/file-{e['data/file_index']:03d}.parquet")
        assert set(rows.column("episode_index").to_pylist()) == {e["episode_index"]}
        assert rows.column("index").to_pylist() == list(range(e["dataset_from_index"], e["dataset_to_index"]))
    assert len(info["abm"]["sha256"]) == 4 + 2 * 4 + 2  # every data and video file is checked on import
    back = tmp_path / "back"
    assert _import(ds, back) == 0
    for seed, ep in eps.items():
        again = load_episode(back / "pick_block" / "seen" / f"episode_{seed:06d}.h5")
        _assert_same_episode(ep, again)
        assert np.array_equal(again.trajectory.joint_positions, ep.trajectory.joint_positions)

    # a limit of about two and a half episodes: files of more than one episode, none of them past the limit
    data_limit = 2.5 * max(_row_group_bytes(p) for p in _data_files(ds)) / MIB
    video_limit = 2.5 * max(p.stat().st_size for p in (ds / "videos").rglob("*.mp4")) / MIB
    ds2 = tmp_path / "ds2"
    _export(data, ds2, "--data-file-mb", f"{data_limit:.6f}", "--video-file-mb", f"{video_limit:.6f}")
    files = _data_files(ds2)
    assert 1 < len(files) < 4
    assert all(_row_group_bytes(p) <= data_limit * MIB for p in files)
    videos = sorted((ds2 / "videos/observation.images.front").rglob("*.mp4"))
    assert 1 < len(videos) < 4 and all(p.stat().st_size <= video_limit * MIB for p in videos)
    episodes = _episode_table(ds2)
    firsts = [e for e in episodes if e["videos/observation.images.front/from_timestamp"] == 0.0]
    assert len(firsts) == len(videos)  # each file's first episode starts at 0 s, the others after it
    back2 = tmp_path / "back2"
    assert _import(ds2, back2) == 0
    for seed, ep in eps.items():
        _assert_same_episode(ep, load_episode(back2 / "pick_block" / "seen" / f"episode_{seed:06d}.h5"))


def _as_format1(ds) -> None:
    """Turn a dense export into what the first abm exports wrote: every extra column under ``observation.*``,
    no ``abm.format`` and no ``frame_sampling`` (the checksums recorded anew, as that export did)."""
    info_path = ds / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    old = {new: old for old in ["observation.depth.front", "observation.depth.wrist", "observation.segmentation.front",
                                "observation.segmentation.wrist", "observation.intrinsics.front",
                                "observation.intrinsics.wrist", "observation.extrinsics.front",
                                "observation.extrinsics.wrist", "observation.gripper_pose", "observation.step",
                                "observation.joint_positions", "action.ee"] for new in [format1_key(old)]}
    path = ds / "data/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    pq.write_table(table.rename_columns([old.get(k, k) for k in table.column_names]), path)
    info["features"] = {old.get(k, k): f for k, f in info["features"].items()}
    del info["abm"]["format"], info["frame_sampling"]
    info["abm"]["sha256"]["data/chunk-000/file-000.parquet"] = sha256_file(path)
    info_path.write_text(json.dumps(info))


def test_exports_of_the_first_format_still_import(tmp_path, cli_errors):
    data, eps = _store(tmp_path, dense=True, seeds=(3,))
    ds = tmp_path / "ds"
    _export(data, ds)
    _as_format1(ds)
    assert "observation.depth.front" in json.loads((ds / "meta" / "info.json").read_text())["features"]
    back = tmp_path / "back"
    assert _import(ds, back) == 0
    again = load_episode(back / "pick_block" / "seen" / "episode_000003.h5")
    _assert_same_episode(eps[3], again)
    assert np.allclose(again.trajectory.ee_actions, eps[3].trajectory.ee_actions, atol=1e-6)
    # one of a newer abm is refused, saying so
    info_path = ds / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["abm"]["format"] = 99
    info_path.write_text(json.dumps(info))
    assert _import(ds, tmp_path / "o") == 2
    assert "newer abm" in cli_errors()[0]
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ datasets written by other tools


FOREIGN_FPS = 10
FOREIGN_FRAMES = 12


def _foreign_motion() -> tuple[np.ndarray, np.ndarray]:
    """TCP positions and gripper opening of a made-up grasp: move (frames 0-5), rest (5-7), close the gripper
    (at 7), lift (7-11). Its keyframes are reached at frames 5 (at rest), 7 (closed) and 11 (the last)."""
    pos = np.zeros((FOREIGN_FRAMES, 3))
    pos[:6] = np.linspace([0.3, 0.0, 0.4], [0.5, 0.1, 0.2], 6)
    pos[6:8] = pos[5]
    pos[8:] = pos[5] + np.outer(np.arange(1, 5), [0, 0, 0.03])
    grip = np.where(np.arange(FOREIGN_FRAMES) < 7, 1.0, 0.0)
    return pos, grip


def _mp4(frames: np.ndarray, fps: int) -> bytes:
    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as c:
        s = c.add_stream("libx264", rate=fps)
        s.width, s.height, s.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        for i, img in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(img, format="rgb24")
            frame.pts = i
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return buffer.getvalue()


def _write_foreign(ds, geometry: bool, episodes: int = 2):
    """A LeRobot v3.0 dataset as lerobot's LeRobotDataset writes one (info.json with its default features and
    file sizes, frames with Hugging Face list columns, one mp4 per camera, the episodes table with its
    bookkeeping and stats columns, tasks.parquet with the task as the pandas index), and no abm section; with
    ``geometry``, depth and calibration of the front camera under the documented keys (the wrist camera has
    none). Returns the frames' RGB, depth and extrinsics of the front camera per episode."""
    rng = np.random.default_rng(7)
    pos, grip = _foreign_motion()
    n = FOREIGN_FRAMES
    state_names = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open", "elbow"]
    features = {
        "observation.images.front": {"dtype": "video", "shape": [RES, RES, 3],
                                     "names": ["height", "width", "channels"], "info": {"video.fps": FOREIGN_FPS}},
        "observation.images.wrist": {"dtype": "video", "shape": [RES, RES, 3],
                                     "names": ["height", "width", "channels"], "info": {"video.fps": FOREIGN_FPS}},
        "observation.state": {"dtype": "float32", "shape": [len(state_names)], "names": state_names},
        "action": {"dtype": "float32", "shape": [7], "names": [f"j{i}" for i in range(7)]},
    }
    if geometry:
        features |= {"geometry.depth.front": {"dtype": "float32", "shape": [RES, RES], "names": ["height", "width"]},
                     "geometry.intrinsics.front": {"dtype": "float64", "shape": [3, 3], "names": None},
                     "geometry.extrinsics.front": {"dtype": "float64", "shape": [4, 4], "names": None}}
    for key in ("timestamp",):
        features[key] = {"dtype": "float32", "shape": [1], "names": None}
    for key in ("frame_index", "episode_index", "index", "task_index"):
        features[key] = {"dtype": "int64", "shape": [1], "names": None}
    cols: dict[str, list] = {k: [] for k, f in features.items() if f["dtype"] != "video"}
    truth, videos, rows = [], {"front": [], "wrist": []}, []
    for e in range(episodes):
        yy, xx = np.mgrid[0:RES, 0:RES]
        rgb = np.stack([np.stack([(xx * 10 + 20 * t + 60 * e) % 256, (yy * 12) % 256, np.full_like(xx, 100)], -1)
                        for t in range(n)]).astype(np.uint8)
        depth = rng.uniform(0.3, 1.5, (n, RES, RES)).astype(np.float32)
        ext = np.tile(np.eye(4), (n, 1, 1))
        ext[:, :3, 3] = [0.6, 0.0, 0.8 + 0.1 * e]
        truth.append((rgb, depth, ext))
        videos["front"].append(rgb)
        videos["wrist"].append(rgb[:, ::-1])
        state = np.concatenate([pos, np.tile([0.0, 1.0, 0.0, 0.0], (n, 1)), grip[:, None], np.ones((n, 1))], 1)
        cols["observation.state"] += state.astype(np.float32).tolist()
        cols["action"] += rng.normal(size=(n, 7)).astype(np.float32).tolist()
        if geometry:
            cols["geometry.depth.front"] += depth.tolist()
            cols["geometry.intrinsics.front"] += [[[18.0, 0, 7.5], [0, 18.0, 7.5], [0, 0, 1]]] * n
            cols["geometry.extrinsics.front"] += ext.tolist()
        cols["timestamp"] += (np.arange(n) / FOREIGN_FPS).tolist()
        cols["frame_index"] += list(range(n))
        cols["episode_index"] += [e] * n
        cols["index"] += list(range(e * n, (e + 1) * n))
        rows.append({"episode_index": e, "tasks": [f"pick up the cube {e}"], "length": n, "data/chunk_index": 0,
                     "data/file_index": 0, "dataset_from_index": e * n, "dataset_to_index": (e + 1) * n,
                     **{f"videos/observation.images.{c}/{k}": v for c in ("front", "wrist") for k, v in
                        (("chunk_index", 0), ("file_index", 0), ("from_timestamp", e * n / FOREIGN_FPS),
                         ("to_timestamp", (e + 1) * n / FOREIGN_FPS))},
                     "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                     "stats/observation.state/mean": state.mean(0).tolist(), "stats/observation.state/count": [n]})
    cols["task_index"] = [e for e in range(episodes) for _ in range(n)]
    types = {"float32": pa.float32(), "float64": pa.float64(), "int64": pa.int64()}
    table = {}
    for key, values in cols.items():
        typ = types[features[key]["dtype"]]
        for _ in features[key]["shape"][1 if features[key]["shape"] == [1] else 0:]:
            typ = pa.list_(typ)  # Hugging Face datasets stores Sequence / Array2D as (variable) lists
        table[key] = pa.array(values, typ)
    (ds / "data/chunk-000").mkdir(parents=True)
    pq.write_table(pa.table(table), ds / "data/chunk-000/file-000.parquet")
    for cam, clips in videos.items():
        path = ds / f"videos/observation.images.{cam}/chunk-000/file-000.mp4"
        path.parent.mkdir(parents=True)
        path.write_bytes(_mp4(np.concatenate(clips), FOREIGN_FPS))
    (ds / "meta/episodes/chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(rows), ds / "meta/episodes/chunk-000/file-000.parquet")
    tasks = pa.table({"task_index": list(range(episodes)), "task": [f"pick up the cube {e}" for e in range(episodes)]})
    pq.write_table(tasks, ds / "meta/tasks.parquet")
    (ds / "meta/stats.json").write_text("{}")
    (ds / "meta/info.json").write_text(json.dumps({
        "codebase_version": "v3.0", "robot_type": "so100", "total_episodes": episodes,
        "total_frames": episodes * n, "total_tasks": episodes, "chunks_size": 1000, "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200, "fps": FOREIGN_FPS, "splits": {"train": f"0:{episodes}"},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": features}))
    return truth


def test_keyframes_are_found_where_the_gripper_changes_or_the_arm_stops():
    pos, grip = _foreign_motion()
    assert detect_keyframes(pos, grip, FOREIGN_FPS).tolist() == [5, 7, 11]
    assert detect_keyframes(pos[:1], grip[:1], FOREIGN_FPS).tolist() == []
    still = np.zeros((4, 3))
    assert detect_keyframes(still, np.ones(4), FOREIGN_FPS).tolist() == [3]  # no motion: only the last frame


def test_a_foreign_dataset_without_depth_is_refused_saying_what_abm_needs(tmp_path, cli_errors):
    ds = tmp_path / "other"
    _write_foreign(ds, geometry=False)
    assert _import(ds, tmp_path / "o", "--task", "pick_block") == 2
    error = cli_errors()[0]
    for words in ("not written by abm data export", "depth and calibration", "geometry.depth.front",
                  "geometry.intrinsics.front", "geometry.extrinsics.front", "camera-to-world", "docs/datasets.md"):
        assert words in error, words
    assert not (tmp_path / "o").exists()


def test_a_foreign_dataset_with_depth_and_calibration_imports(tmp_path, cli_errors, capsys):
    ds = tmp_path / "other"
    truth = _write_foreign(ds, geometry=True)
    assert _import(ds, tmp_path / "o") == 2  # LeRobot datasets name no ABM-Bench task
    assert "pass --task" in cli_errors()[0] and not (tmp_path / "o").exists()
    assert _import(ds, tmp_path / "o", "--task", "no_such_task") == 2
    assert "not an ABM-Bench task" in cli_errors()[0]

    out = tmp_path / "out"
    assert _import(ds, out, "--task", "pick_block", "--split", "unseen") == 0
    assert "cameras without depth and calibration are left out: wrist" in capsys.readouterr().err
    pos, grip = _foreign_motion()
    for e, (rgb, depth, ext) in enumerate(truth):
        ep = load_episode(out / "pick_block" / "unseen" / f"episode_{e:06d}.h5")
        assert (ep.task, ep.split, ep.instruction, ep.success) == ("pick_block", "unseen", f"pick up the cube {e}",
                                                                   True)
        assert ep.metadata["lerobot_episode_index"] == e and ep.trajectory is None
        frames = [0, 5, 7]  # the observations: the start of each segment; the targets: 5, 7, 11
        assert len(ep.steps) == 3
        for (obs, action), f, target in zip(ep.steps, frames, [5, 7, 11], strict=True):
            assert list(obs.cameras) == ["front"]
            cam = obs.cameras["front"]
            assert np.array_equal(cam.depth, depth[f]) and np.array_equal(cam.extrinsics, ext[f])
            assert cam.intrinsics[0, 0] == 18.0 and cam.segmentation is None
            assert np.abs(cam.rgb.astype(int) - rgb[f].astype(int)).mean() < RGB_TOL
            assert np.allclose(obs.gripper_pose[:3, 3], pos[f], atol=1e-6) and obs.gripper_open == grip[f]
            assert np.allclose(action.position, pos[target], atol=1e-6)
            assert action.gripper_open == bool(grip[target])
    assert [a.gripper_open for _, a in ep.steps] == [True, False, False]


def _as_text(path, column: str) -> None:
    """Rewrite ``column`` of the parquet file ``path`` with the same nesting but text ("abc") in every cell."""
    table = pq.read_table(path)

    def text(value):
        return [text(v) for v in value] if isinstance(value, list) else "abc"

    def text_type(typ):
        nested = pa.types.is_list(typ) or pa.types.is_fixed_size_list(typ)
        return pa.list_(text_type(typ.value_type)) if nested else pa.string()

    i = table.schema.get_field_index(column)
    values = pa.array([text(v) for v in table.column(column).to_pylist()], text_type(table.schema.field(i).type))
    pq.write_table(table.set_column(i, column, values), path)


@pytest.mark.parametrize("column", ["observation.state", "geometry.depth.front", "geometry.extrinsics.front"])
def test_a_number_column_holding_text_is_one_error_line(tmp_path, cli_errors, column):
    ds = tmp_path / "other"
    _write_foreign(ds, geometry=True)
    frames = ds / "data/chunk-000/file-000.parquet"
    _as_text(frames, column)
    assert _import(ds, tmp_path / "o", "--task", "pick_block") == 2
    declared = "float32" if column != "geometry.extrinsics.front" else "float64"
    assert cli_errors() == [f"abm: error: {frames}: column {column!r} holds text (e.g. 'abc'), not numbers; "
                            f"meta/info.json declares it {declared!r}: write the column as numbers (or import a "
                            "dataset whose frames match its features)"]
    assert not (tmp_path / "o").exists()  # refused before anything was written


def test_a_number_column_of_an_abm_export_holding_text_is_one_error_line(tmp_path, cli_errors):
    data, _ = _store(tmp_path, dense=False, seeds=(0,))
    ds = tmp_path / "ds"
    info = _export(data, ds)
    frames = ds / "data/chunk-000/file-000.parquet"
    _as_text(frames, "robot.gripper_pose")
    info["abm"]["sha256"]["data/chunk-000/file-000.parquet"] = sha256_file(frames)  # edited with its checksum
    (ds / "meta" / "info.json").write_text(json.dumps(info))
    assert _import(ds, tmp_path / "o") == 2
    assert cli_errors() == [f"abm: error: {frames}: column 'robot.gripper_pose' holds text (e.g. 'abc'), not "
                            "numbers; meta/info.json declares it 'float64': write the column as numbers (or import "
                            "a dataset whose frames match its features)"]


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

    assert _import(tmp_path / "missing", tmp_path / "o") == 2
    assert "not found" in capsys.readouterr().err
    (tmp_path / "notds").mkdir()
    assert _import(tmp_path / "notds", tmp_path / "o") == 2
    assert "not a LeRobot dataset" in capsys.readouterr().err

    info = _export(data, ds)
    info_path = ds / "meta" / "info.json"
    info_path.write_text("{not json")
    assert _import(ds, tmp_path / "o") == 2
    assert "not valid JSON" in capsys.readouterr().err
    info_path.write_text(json.dumps({**info, "codebase_version": "v2.1"}))
    assert _import(ds, tmp_path / "o") == 2
    assert "version 'v2.1'" in capsys.readouterr().err
    info_path.write_text(json.dumps(info))
    assert _import(ds, tmp_path / "o", "--task", "pick_block") == 2  # abm's exports name their own tasks
    assert "--task and --split are for LeRobot datasets written by other tools" in capsys.readouterr().err
    info_path.write_text(json.dumps({k: v for k, v in info.items() if k != "abm"}))
    assert _import(ds, tmp_path / "o") == 2  # without its abm section it reads as another tool's dataset
    assert "no abm section" in capsys.readouterr().err
    info_path.write_text(json.dumps({**info, "abm": {**info["abm"], "sha256": {
        **info["abm"]["sha256"], "../outside.parquet": "0" * 64}}}))
    assert _import(ds, tmp_path / "o") == 2
    assert "not inside the dataset" in capsys.readouterr().err
    unchecked = {k: v for k, v in info["abm"]["sha256"].items() if not k.startswith("data/")}
    info_path.write_text(json.dumps({**info, "abm": {**info["abm"], "sha256": unchecked}}))
    assert _import(ds, tmp_path / "o") == 2  # every file the import reads must have its checksum recorded
    assert "records no checksum of data/chunk-000/file-000.parquet" in capsys.readouterr().err
    info_path.write_text(json.dumps(info))
    (ds / "data/chunk-000/file-000.parquet").write_bytes(b"garbage")
    assert _import(ds, tmp_path / "o") == 2
    assert "does not match the checksum the export recorded" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before anything was written
    # exporting into a non-empty folder is refused
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 2
    assert "not an empty folder" in capsys.readouterr().err
    assert info_path.exists()  # and the existing dataset is left alone


def test_the_export_loads_with_lerobots_parquet_loader(tmp_path):
    """LeRobot 0.4 reads the frames with Hugging Face ``datasets`` (features mapped from info.json: image ->
    Image, shape (1,) -> Value, 1-D -> Sequence, 2-D -> Array2D) and the tasks with pandas (task string as the
    index). The lerobot package itself is not installed here (it pulls torchvision); this runs where datasets
    and pandas are installed and is skipped elsewhere."""
    datasets = pytest.importorskip("datasets")
    pd = pytest.importorskip("pandas")
    for dense in (True, False):
        data, eps = _store(tmp_path / str(dense), dense=True, seeds=(2,))
        ds = tmp_path / str(dense) / "ds"
        info = _export(data, ds, "--frames", "dense" if dense else "keyframes")
        feats = {}
        for key, ft in info["features"].items():
            shape = tuple(ft["shape"])
            if ft["dtype"] == "video":
                continue
            feats[key] = (datasets.Image() if ft["dtype"] == "image" else datasets.Value(ft["dtype"])
                          if shape == (1,) else datasets.Sequence(length=shape[0], feature=datasets.Value(ft["dtype"]))
                          if len(shape) == 1 else datasets.Array2D(shape=shape, dtype=ft["dtype"]))
        parquet = ds / info["data_path"].format(chunk_index=0, file_index=0)
        frames = datasets.load_dataset("parquet", data_files=str(parquet), features=datasets.Features(feats),
                                       split="train", cache_dir=str(tmp_path / "hf"))
        assert frames.num_rows == info["total_frames"] == (9 if dense else 3)
        row = frames.with_format("numpy")[1 if not dense else 3]
        observation = eps[2].trajectory.observations[3]
        assert np.array_equal(row["geometry.depth.front"], observation.cameras["front"].depth)
        assert bool(row["keyframe.is_keyframe"]) and row["keyframe.kind"] == "grasp"
        if not dense:
            assert np.array_equal(np.asarray(frames[1]["observation.images.front"]), observation.cameras["front"].rgb)
        tasks = pd.read_parquet(ds / "meta" / "tasks.parquet")
        assert tasks.index.name == "task" and tasks.loc["pick up the block 2", "task_index"] == 0


@pytest.mark.parametrize("argv, words", [
    (["data", "export"], ["LeRobot v3.0", "--frames", "--crf", "--data-file-mb", "--video-file-mb", "geometry.*"]),
    (["data", "import"], ["LeRobot v3.0", "--out", "--task", "--split", "geometry.depth.<camera>"]),
    (["data", "generate"], ["--dense", "--dense-fps", "--backend", "--ray-address"]),
    (["eval"], ["--backend", "--ray-address"]),
])
def test_new_options_have_help(argv, words, capsys):
    with pytest.raises(SystemExit) as done:
        main([*argv, "--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # as wrapped for any terminal width
    assert all(w in text for w in words), [w for w in words if w not in text]


class _Array2D(pa.ExtensionType):
    """An arrow extension type like Hugging Face ``datasets``' ``Array2D``, which a process that imported
    ``datasets`` (as LeRobot always does) reads LeRobot-written 2-D columns as."""

    def __init__(self, storage_type: pa.DataType) -> None:
        super().__init__(storage_type, "abm-test.array2d")

    def __arrow_ext_serialize__(self) -> bytes:
        return b""

    @classmethod
    def __arrow_ext_deserialize__(cls, storage_type: pa.DataType, serialized: bytes) -> "_Array2D":
        return cls(storage_type)


def test_columns_read_as_extension_types_import_as_their_values(tmp_path, cli_errors):
    ds = tmp_path / "other"
    truth = _write_foreign(ds, geometry=True, episodes=1)
    frames = ds / "data/chunk-000/file-000.parquet"
    table = pq.read_table(frames)
    i = table.schema.get_field_index("geometry.depth.front")
    storage = table.column(i).combine_chunks()
    wrapped = pa.ExtensionArray.from_storage(_Array2D(storage.type), storage)
    pq.write_table(table.set_column(i, "geometry.depth.front", wrapped), frames)
    pa.register_extension_type(_Array2D(storage.type))
    try:
        assert isinstance(pq.read_table(frames).schema.field(i).type, _Array2D)  # what the importer now meets
        assert _import(ds, tmp_path / "out", "--task", "pick_block") == 0, cli_errors()
    finally:
        pa.unregister_extension_type("abm-test.array2d")
    ep = load_episode(tmp_path / "out" / "pick_block" / "seen" / "episode_000000.h5")
    assert np.array_equal(ep.steps[0][0].cameras["front"].depth, truth[0][1][0])
