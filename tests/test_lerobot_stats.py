"""The statistics of LeRobot exports carry the quantiles LeRobot's normalisers read (q01 / q99 for
``NormalizationMode.QUANTILES``, q10 / q90 for ``QUANTILE10``): known arrays give known quantiles, per episode
and in ``meta/stats.json``, in LeRobot's shapes."""

import json

import numpy as np
import pytest

from abm.data.lerobot_stats import QUANTILES, aggregate_stats, feature_stats, quantile_key

SCALAR = {"dtype": "float32", "shape": [1]}
VECTOR = {"dtype": "float32", "shape": [2]}
QUANTILE_KEYS = ["q01", "q10", "q50", "q90", "q99"]


def test_the_quantile_names_are_lerobots():
    assert [quantile_key(q) for q in QUANTILES] == QUANTILE_KEYS


def test_a_vector_gets_each_elements_quantiles():
    ramp = np.arange(101, dtype=np.float64)  # 0, 1, ..., 100: the p-th quantile is p
    values = np.stack([ramp, 1000 - 10 * ramp], axis=1)[np.random.default_rng(0).permutation(101)]
    st = feature_stats(VECTOR, values)
    assert st is not None
    for key, p in zip(QUANTILE_KEYS, (1, 10, 50, 90, 99), strict=True):
        assert st[key].shape == (2,)
        assert np.allclose(st[key], [p, 1000 - 10 * (100 - p)]), key
    assert st["min"].tolist() == [0, 0] and st["max"].tolist() == [100, 1000] and st["count"].tolist() == [101]


def test_quantiles_interpolate_between_samples_and_skip_nan():
    st = feature_stats(SCALAR, np.array([np.nan, 4.0, 0.0, np.nan, 2.0]))  # 0, 2, 4 known
    assert st is not None
    assert st["q50"].tolist() == [2.0] and st["q10"].tolist() == pytest.approx([0.4])
    assert st["q99"].tolist() == pytest.approx([3.96]) and st["count"].tolist() == [5]
    assert feature_stats(SCALAR, np.full(3, np.nan)) is None


def test_a_camera_gets_per_channel_quantiles_in_0_1():
    img = np.zeros((2, 10, 10, 3), np.uint8)
    img[..., 0] = np.arange(100, dtype=np.uint8).reshape(10, 10)  # red: 0..99 in both frames
    img[..., 1] = 255
    st = feature_stats({"dtype": "video", "shape": [10, 10, 3]}, img)
    assert st is not None
    assert st["q50"].shape == (3, 1, 1)  # LeRobot checks this shape for cameras
    assert st["q50"].ravel() == pytest.approx([49.5 / 255, 1.0, 0.0])
    assert st["q01"].ravel()[0] == pytest.approx(np.quantile(np.arange(100.0).repeat(2), 0.01) / 255)


def test_the_dataset_quantiles_are_the_count_weighted_mean_of_the_episodes_as_lerobot_pools_them():
    one = feature_stats(SCALAR, np.arange(11.0))  # q50 5, 11 frames
    two = feature_stats(SCALAR, np.arange(100.0, 133.0))  # q50 116, 33 frames
    assert one is not None and two is not None
    pooled = aggregate_stats([one, two])
    assert pooled["q50"] == pytest.approx([(5 * 11 + 116 * 33) / 44])
    assert pooled["count"] == [44] and pooled["min"] == [0.0] and pooled["max"] == [132.0]
    alone = aggregate_stats([one])
    assert all(alone[k] == pytest.approx(one[k].tolist()) for k in QUANTILE_KEYS)


def test_exports_write_the_quantiles_per_episode_and_in_stats_json(tmp_path):
    pytest.importorskip("h5py")
    pytest.importorskip("av")
    pq = pytest.importorskip("pyarrow.parquet")
    from abm.data.episode_store import save_episode
    from abm.data.lerobot import export_lerobot
    from test_lerobot import make_episode

    data = tmp_path / "data"
    for seed in (0, 1):
        save_episode(make_episode(seed, keyframes=3), data / "pick_block" / "seen" / f"episode_{seed:06d}.h5")
    export_lerobot(data, tmp_path / "ds", progress=False)
    frames = pq.read_table(tmp_path / "ds/data/chunk-000/file-000.parquet")
    state = np.stack(frames.column("observation.state").to_pylist())
    episodes = pq.read_table(tmp_path / "ds/meta/episodes/chunk-000/file-000.parquet").to_pylist()
    for ep in episodes:
        mine = state[ep["dataset_from_index"]:ep["dataset_to_index"]]
        for key, q in zip(QUANTILE_KEYS, QUANTILES, strict=True):
            assert np.allclose(ep[f"stats/observation.state/{key}"], np.quantile(mine.astype(np.float64), q, axis=0))
        assert np.array(ep["stats/observation.images.front/q99"]).shape == (3, 1, 1)
    stats = json.loads((tmp_path / "ds/meta/stats.json").read_text())
    q99 = np.mean([ep["stats/observation.state/q99"] for ep in episodes], axis=0)  # equal frame counts
    assert np.allclose(stats["observation.state"]["q99"], q99)
    assert set(QUANTILE_KEYS) <= set(stats["action"]) and set(QUANTILE_KEYS) <= set(stats["geometry.depth.front"])
