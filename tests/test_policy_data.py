"""Keyframe dataset and the policy's rendering of its samples: contents per variant, determinism,
padding, workers, sampler sharding/resume."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

import abm.data.keyframes as keyframes
from abm.data.keyframes import KeyframeDataset, StepSampler, collate
from abm.errors import ConfigError
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.language import HashLanguageEncoder
from abm.train.synthetic import synthetic_episodes

LANG = 32


@pytest.fixture(scope="module")
def episodes():
    return synthetic_episodes(3, camera_resolution=48)


def _policy(variant: str, resolution: int = 48) -> KeyframePolicy:
    cfg = PolicyConfig.from_preset("small", variant, resolution=resolution, lang_dim=LANG, ifd_feature_dim=8)
    return KeyframePolicy(cfg, HashLanguageEncoder(LANG))


def _dataset(episodes, policy: KeyframePolicy, **kw) -> KeyframeDataset:
    return KeyframeDataset(episodes, policy.workspace, **policy.sample_options(), **kw)


@pytest.mark.parametrize("variant", ["abm", "rvt", "stack", "concat-rerendered", "concat-full"])
def test_sample_contents(episodes, variant: str) -> None:
    policy = _policy(variant)
    ds = _dataset(episodes, policy)
    assert len(ds) == 6
    s = ds[(1, 7)]
    n = s["points"].shape[0]
    assert s["points"].shape == (n, 3) and s["colors"].shape == (n, 3) and n > 100
    assert s["gripper_position"].shape == (3,) and s["action_position"].shape == (3,)
    assert s["action_quaternion"].shape == (4,) and "images" not in s  # the policy renders, not the dataset
    inputs = policy.model_inputs(collate([s]))
    assert inputs["images"].shape == (1, 5, 10, 48, 48)
    assert inputs["lang"].shape == (1, 77, LANG) and inputs["proprio"].shape == (1, 4)
    if variant == "rvt":
        assert "mask" not in inputs and "point_mask" not in s
        assert "block" in policy.language_goal(s["instruction"], s["skill"])  # full instruction
    else:
        assert s["point_mask"].shape == (n,) and s["point_mask"].sum() > 0
        assert policy.language_goal(s["instruction"], s["skill"]) == "put X on the target"  # skill text only
        per_view = inputs["mask"][0].sum((1, 2, 3))
        assert inputs["mask"].shape == (1, 5, 1, 48, 48)
        if variant == "abm":
            assert torch.all(per_view <= 1) and per_view.sum() >= 3  # one centre pixel per view
        else:
            assert per_view.sum() > 5


def test_center_pixel_is_on_target_and_action_moves_with_augmentation(episodes) -> None:
    policy = _policy("abm")
    ds = _dataset(episodes, policy)
    a, b, c = ds[(0, 1)], ds[(0, 1)], ds[(0, 2)]
    for k in a:
        if isinstance(a[k], torch.Tensor):
            torch.testing.assert_close(a[k], b[k])  # same key -> same sample
    assert not torch.allclose(a["action_position"], c["action_position"])  # another seed -> another augmentation
    plain = _dataset(episodes, policy, augment=False)[(0, 1)]
    grasp = episodes[0].steps[0][1].position
    np.testing.assert_allclose(plain["action_position"].numpy(), grasp, atol=1e-5)
    # the centre pixel of the top view is near the grasp point's projection (target block top)
    uv, _ = policy.renderer.project(torch.tensor(grasp, dtype=torch.float32))
    mask = policy.model_inputs(collate([plain]))["mask"][0]
    row, col = mask[4, 0].nonzero()[0].tolist()
    assert abs(col - uv[4, 0]) < 4 and abs(row - uv[4, 1]) < 4


def test_padded_batch_renders_like_single_samples(episodes) -> None:
    policy = _policy("abm")
    ds = _dataset(episodes, policy, augment=False)
    short = dict(ds[3])
    for key in ("points", "colors", "point_mask", "point_heatmap"):
        short[key] = short[key][:-500]  # a smaller cloud, so the batch pads it
    samples = [ds[0], short]
    batch = collate(samples)
    assert batch["valid"].sum(1).tolist() == [s["points"].shape[0] for s in samples]
    together = policy.model_inputs(batch)
    for i, s in enumerate(samples):
        alone = policy.model_inputs(collate([s]))
        for key in ("images", "mask", "proprio", "lang"):
            torch.testing.assert_close(together[key][i], alone[key][0], msg=key)


def test_ifd_features_through_index_map(episodes, monkeypatch, tmp_path) -> None:
    class FakeClip:
        def point_features(self, observation, cloud):
            return np.tile(cloud.rgb, (1, 3))[:, :8].astype(np.float32)  # (N, 8)

        def ground(self, *a):  # pragma: no cover - not used by ifd
            raise AssertionError

    monkeypatch.setattr(keyframes, "build_grounder", lambda config: FakeClip())
    policy = _policy("ifd")
    with pytest.raises(ValueError, match="lacks 6 of 6 keyframes.*abm data ground"):
        _dataset(episodes, policy, grounder={"kind": "clip"}, cache_dir=tmp_path)  # grounding is an explicit step
    made = keyframes.ground_keyframes(episodes, policy.workspace, {"kind": "clip"}, tmp_path, mask=False,
                                      features=True, show_progress=False)
    assert made == 6 and len(list(tmp_path.glob("*.npz"))) == 6
    assert keyframes.ground_keyframes(episodes, policy.workspace, {"kind": "clip"}, tmp_path, mask=False,
                                      features=True, show_progress=False) == 0  # resumable: nothing left
    ds = _dataset(episodes, policy, grounder={"kind": "clip"}, cache_dir=tmp_path)
    s = ds[(0, 0)]
    assert s["feature_table"].shape == (s["points"].shape[0], 8)  # point features of its own: one row per point
    assert torch.equal(s["feature_row"], torch.arange(s["points"].shape[0], dtype=torch.int32))
    inputs = policy.model_inputs(collate([s, ds[(1, 1)]]))
    idx, feats = inputs["ifd_index"], inputs["ifd_features"]
    assert idx.shape == (2, 5, 48, 48) and feats.shape[0] == 2 and feats.shape[2] == 8
    assert idx[0].max() < feats.shape[1] and (idx[0] >= 0).sum() > 100
    # the gathered feature of a visible pixel equals its rendered colour (fp16 cache tolerance)
    v, r, c = (idx[0] >= 0).nonzero()[0].tolist()
    torch.testing.assert_close(feats[0, idx[0, v, r, c], :3], inputs["images"][0, v, :3, r, c], atol=2e-3, rtol=0)
    wrong = _policy("ifd")
    wrong.config.ifd_feature_dim = 16
    with pytest.raises(ValueError, match="ifd_feature_dim"):
        wrong.model_inputs(collate([s]))


def test_a_cached_patch_table_gives_the_features_and_predictions_of_the_per_point_array(episodes, monkeypatch,
                                                                                      tmp_path) -> None:
    """A grounder's patch table is cached with only the rows some point uses (not the ``(N, F)`` array that
    entries written before tables hold); both give every point the same feature and the network the same
    input at every pixel and the same output."""
    from abm.grounding.feature_cloud import LiftedFeatures

    class TableClip:
        def lifted_features(self, observation, cloud):
            table = np.random.default_rng(0).standard_normal((300, 8)).astype(np.float32)
            return LiftedFeatures(table, (np.arange(len(cloud)) * 7) % 250)  # rows 250..299 unused

        def point_features(self, observation, cloud):  # pragma: no cover - lifted_features is preferred
            raise AssertionError

    monkeypatch.setattr(keyframes, "build_grounder", lambda config: TableClip())
    policy = _policy("ifd")
    tables, dense = tmp_path / "tables", tmp_path / "dense"
    keyframes.ground_keyframes(episodes, policy.workspace, {"kind": "clip"}, tables, mask=False, features=True,
                               show_progress=False)
    dense.mkdir()
    for entry in tables.glob("*.npz"):  # the same features as an entry written before tables
        with np.load(entry) as data:
            np.savez(dense / entry.name, features=data["feature_table"][data["feature_row"]])
    ds, ds_dense = (_dataset(episodes, policy, grounder={"kind": "clip"}, cache_dir=c) for c in (tables, dense))
    keys = [(0, 0), (1, 1)]
    for key in keys:
        s, old = ds[key], ds_dense[key]
        n = s["points"].shape[0]
        assert s["feature_table"].shape == (250, 8) and old["feature_table"].shape == (n, 8)
        assert torch.equal(s["feature_table"][s["feature_row"]], old["feature_table"][old["feature_row"]])
    size = {c.name: sum(f.stat().st_size for f in c.glob("*.npz")) for c in (tables, dense)}
    assert size["tables"] * 3 < size["dense"]  # 250 rows of 8 and an int32 per point, not 8 float16 per point
    batch, batch_dense = collate([ds[k] for k in keys]), collate([ds_dense[k] for k in keys])
    assert batch["feature_table"].shape == (2, 250, 8)
    with torch.no_grad():
        inputs, inputs_dense = policy.model_inputs(batch), policy.model_inputs(batch_dense)
        assert inputs["ifd_features"].shape[1] < inputs_dense["ifd_features"].shape[1]  # patches, not points
        assert torch.equal(_pixel_features(inputs), _pixel_features(inputs_dense))
        assert torch.equal(inputs["images"], inputs_dense["images"])
        out, out_dense = policy.model(**inputs), policy.model(**inputs_dense)
        # a table and a per-point entry padded into one batch: each sample's pixels are those it has alone
        mixed = _pixel_features(policy.model_inputs(collate([ds[keys[0]], ds_dense[keys[1]]])))
        alone = [_pixel_features(policy.model_inputs(collate([d[k]]))) for d, k in ((ds, keys[0]), (ds_dense, keys[1]))]
        assert torch.equal(mixed[0], alone[0][0]) and torch.equal(mixed[1], alone[1][0])
    torch.testing.assert_close(out.heatmap, out_dense.heatmap, atol=1e-6, rtol=0)
    torch.testing.assert_close(out.rotation, out_dense.rotation, atol=1e-6, rtol=0)


def _pixel_features(inputs: dict[str, torch.Tensor]) -> torch.Tensor:
    """``(B, V*H*W, F)``: the CLIP feature each pixel of the views shows (zero where empty)."""
    idx = inputs["ifd_index"].flatten(1)
    return torch.stack([f[i.clamp(min=0)] * (i >= 0).unsqueeze(-1)
                        for f, i in zip(inputs["ifd_features"], idx, strict=True)])


def test_workers_give_the_same_batches(episodes) -> None:
    ds = _dataset(episodes, _policy("abm"))
    pickle.dumps(ds)  # nothing unpicklable
    batches = []
    for workers in (0, 2):
        sampler = StepSampler(len(ds), 2, steps=2, seed=3)
        loader = torch.utils.data.DataLoader(ds, batch_size=2, sampler=sampler, num_workers=workers,
                                             collate_fn=collate, worker_init_fn=keyframes.worker_init)
        batches.append(list(loader))
    for b0, b2 in zip(*batches, strict=True):
        for k in b0:
            if isinstance(b0[k], torch.Tensor):
                torch.testing.assert_close(b0[k], b2[k])
            else:
                assert b0[k] == b2[k]


@pytest.mark.parametrize("variant", ["abm", "rvt"])
def test_keyframes_kept_in_memory_give_the_same_samples(episodes, variant, monkeypatch) -> None:
    policy = _policy(variant)
    fresh, kept = _dataset(episodes, policy, memory_mb=0), _dataset(episodes, policy)
    computed = []
    real = kept._conditioned
    monkeypatch.setattr(kept, "_conditioned", lambda j, k, obs: computed.append((j, k)) or real(j, k, obs))
    for draw in range(3 * len(kept)):  # every keyframe three times, each with its own augmentation
        key = (draw % len(kept), draw)
        a, b = fresh[key], kept[key]
        assert set(a) == set(b)
        for name in a:
            assert a[name] == b[name] if isinstance(a[name], str) else torch.equal(a[name], b[name]), name
    assert len(computed) == len(kept)  # fused and grounded once per keyframe
    assert fresh._memory_used == 0 and kept._memory_used > 0


def test_the_keyframe_memory_keeps_to_its_budget(episodes) -> None:
    policy = _policy("abm")
    one = _dataset(episodes, policy)
    one[0]
    size = one._memory_used
    small = _dataset(episodes, policy, memory_mb=2.5 * size / 2**20)  # room for two keyframes
    for i in range(len(small)):
        small[i]
    assert len(small._memory) == 2 and small._memory_used <= small.memory_bytes
    with pytest.raises(ConfigError, match="memory_mb must be >= 0"):
        _dataset(episodes, policy, memory_mb=-1)


def test_step_sampler_sharding_and_resume() -> None:
    full = list(StepSampler(10, 3, steps=8, seed=1))
    resumed = list(StepSampler(10, 3, steps=8, start_step=5, seed=1))
    assert resumed == full[15:]
    ranks = [list(StepSampler(10, 2, steps=5, world_size=2, rank=r, seed=1)) for r in range(2)]
    seeds = [s for r in ranks for _, s in r]
    assert len(set(seeds)) == 20  # every global position used exactly once across ranks
    epoch0 = sorted(i for r in ranks for i, s in r if s < 10)
    assert epoch0 == list(range(10))  # each epoch is a permutation
    with pytest.raises(ValueError, match="empty"):
        StepSampler(0, 2, steps=1)


class _FakeStore:
    """The EpisodeStore API the dataset relies on (index without images, lazy per-step loading)."""

    def __init__(self, episodes) -> None:
        from types import SimpleNamespace

        self._eps = episodes
        self.episodes = [SimpleNamespace(path=f"ep{i}.h5", task=e.task, split=e.split, instruction=e.instruction,
                                         num_keyframes=len(e), variation=0, success=True, seed=i)
                         for i, e in enumerate(episodes)]
        self.loaded_steps: list[tuple[int, int]] = []

    def load(self, i):
        return self._eps[i]

    def load_step(self, i, k):
        self.loaded_steps.append((i, k))
        return self._eps[i].steps[k]

    def select(self, tasks=None, splits=None):
        return [i for i, e in enumerate(self.episodes) if (not tasks or e.task in tasks)
                and (not splits or e.split in splits)]


def test_dataset_over_an_episode_store(episodes) -> None:
    store = _FakeStore(episodes)
    source = keyframes.EpisodeSource(store, store.select(tasks=["pick_block"]))
    ds = _dataset(source, _policy("abm", resolution=32))
    assert len(ds) == 6 and ds.source.meta[1].key == "ep1.h5"
    s = ds[(3, 0)]
    assert s["point_mask"].sum() > 0 and store.loaded_steps[-1] == (1, 1)
    pickle.dumps(ds)


def test_keyframes_outside_the_workspace_are_refused(episodes) -> None:
    from abm.geometry import Workspace

    small = Workspace((0.5, 0.0, 0.35), 0.05)  # 5 cm around a point above the table: no keyframe fits
    with pytest.raises(ValueError, match=r"6 keyframes of 3 episodes lie outside .*\(--workspace-size M"):
        KeyframeDataset(episodes, small)


def test_margin_cube_holds_every_point_augmentation_can_move_into_view():
    import numpy as np

    from abm.data.keyframes import augmentation_margin_cube
    from abm.geometry import Workspace, random_se3

    ws = Workspace()
    margin = augmentation_margin_cube(ws, 0.125, 45.0)
    assert margin.size == pytest.approx(2 * (0.5 + 0.125) * np.sqrt(2))
    assert augmentation_margin_cube(ws, 0.0, 0.0).size == pytest.approx(ws.size)
    rng = np.random.default_rng(0)
    inside = rng.uniform(ws.lower, ws.upper, (2000, 3))
    inside[:8] = np.array(np.meshgrid(*zip(ws.lower, ws.upper, strict=True))).reshape(3, -1).T  # the corners
    for _ in range(50):
        t = random_se3(rng, ws, 0.125, 45.0)
        source = (inside - t[:3, 3]) @ t[:3, :3]  # where the points that land inside came from
        assert margin.contains(source).all()
