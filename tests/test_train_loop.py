"""Training: overfitting a tiny batch, exact resume after an interruption, CLI errors, loading a policy."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from abm.cli import main as cli_main
from abm.data.keyframes import KeyframeDataset, collate
from abm.grounding.config import ClipGrounderConfig
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.checkpoint import list_checkpoints
from abm.policy.language import HashLanguageEncoder
from abm.train import TrainConfig, train
from abm.train.synthetic import synthetic_episodes
from abm.types import KeyframeAction
from conftest import TINY_POLICY as TINY


@pytest.fixture(scope="module")
def episodes():
    return synthetic_episodes(3, camera_resolution=40)


def test_small_model_overfits_a_fixed_batch(episodes) -> None:
    torch.manual_seed(0)
    # the small preset's depth (2 + 2 layers) at 32^2 views and width 64, so it takes ~50 steps / ~2 s
    cfg = PolicyConfig.from_preset("small", "abm", resolution=32, width=64, stem_channels=16, decoder_channels=8,
                                   lang_dim=32)
    policy = KeyframePolicy(cfg, HashLanguageEncoder(32))
    ds = KeyframeDataset(episodes[:1], policy.workspace, **policy.sample_options(), augment=False)
    batch = collate([ds[0], ds[1]])
    opt = torch.optim.Adam(policy.parameters(), lr=2e-3)
    losses = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a tiny model: one thread is as fast, and immune to a busy machine's other processes
    try:
        _overfit(policy, batch, opt, losses)
    finally:
        torch.set_num_threads(threads)
    assert losses[-1] < 0.1 * losses[0], (losses[0], losses[-1], len(losses))


def _overfit(policy: KeyframePolicy, batch: dict, opt: torch.optim.Optimizer, losses: list[float]) -> None:
    for _ in range(150):
        loss, metrics = policy.compute_loss(batch)
        assert set(metrics) == {"total", "translation", "rotation", "gripper", "collision", "zoom_translation"}
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if losses[-1] < 0.1 * losses[0]:
            break


def _cfg(tmp_path, **kw) -> TrainConfig:
    base = dict(method="abm", preset="small", out=tmp_path, steps=6, batch=2, checkpoint_every=2, log_every=1,
                policy=dict(TINY), progress=False, warmup=2, lr=3e-3)
    base.update(kw)
    return TrainConfig(**base)


def test_resume_after_interruption_reproduces_the_loss_curve(episodes, tmp_path) -> None:
    ref: dict[int, float] = {}
    train(_cfg(tmp_path / "ref"), episodes, on_step=lambda s, losses: ref.__setitem__(s, losses["total"]))

    class Crash(Exception):
        pass

    def crash_at_5(step: int, losses: dict) -> None:
        if step == 5:
            raise Crash

    with pytest.raises(Crash):
        train(_cfg(tmp_path / "run"), episodes, on_step=crash_at_5)
    assert [s for s, _ in list_checkpoints(tmp_path / "run")] == [2, 4]
    resumed: dict[int, float] = {}
    summary = train(_cfg(tmp_path / "run", resume=True), episodes,
                    on_step=lambda s, losses: resumed.__setitem__(s, losses["total"]))
    assert sorted(resumed) == [5, 6]
    for s in (5, 6):
        assert resumed[s] == pytest.approx(ref[s], rel=1e-5, abs=1e-5)
    assert summary["steps"] == 6
    ref_ckpt = torch.load(tmp_path / "ref/checkpoints/step_00000006.pt", weights_only=True)
    run_ckpt = torch.load(tmp_path / "run/checkpoints/step_00000006.pt", weights_only=True)
    for k, v in ref_ckpt["model"].items():
        torch.testing.assert_close(run_ckpt["model"][k], v, rtol=1e-4, atol=1e-5)
    rows = (tmp_path / "run/log.csv").read_text().strip().splitlines()
    assert [int(r.split(",")[0]) for r in rows[1:]] == [1, 2, 3, 4, 5, 6]  # no duplicated steps
    elapsed = [float(r.split(",")[-1]) for r in rows[1:]]
    assert elapsed == sorted(elapsed)  # training time continues across the resume
    assert (tmp_path / "run/tb").is_dir() and json.loads((tmp_path / "run/summary.json").read_text())


def test_adamw_optimizer_trains_and_resumes_and_unknown_optimizer_fails(episodes, tmp_path) -> None:
    summary = train(_cfg(tmp_path / "adamw", optimizer="adamw", steps=2, checkpoint_every=1), episodes)
    assert summary["steps"] == 2
    ckpt = torch.load(tmp_path / "adamw/checkpoints/step_00000002.pt", weights_only=True)
    assert "amsgrad" in ckpt["optimizer"]["param_groups"][0]  # AdamW's state, not LAMB's
    summary = train(_cfg(tmp_path / "adamw", optimizer="adamw", steps=3, resume=True), episodes)
    assert summary["steps"] == 3
    with pytest.raises(ValueError, match="unknown optimizer 'sgd'"):
        train(_cfg(tmp_path / "sgd", optimizer="sgd"), episodes)


def test_adamw_is_fused_and_a_restored_per_tensor_state_continues_fused() -> None:
    """make_optimizer's AdamW runs torch's fused kernel; the state of a per-tensor AdamW (a checkpoint from before)
    loads into it and continues the same updates within float rounding."""
    from abm.train.loop import make_optimizer, use_fused_adamw

    torch.manual_seed(0)
    start = [torch.randn(5, 3), torch.randn(7)]
    grads = [[torch.randn_like(p) for p in start] for _ in range(6)]

    def run(opt: torch.optim.Optimizer, params: list[torch.Tensor], steps: range) -> None:
        for i in steps:
            for p, g in zip(params, grads[i], strict=True):
                p.grad = g.clone()
            opt.step()

    ref = [torch.nn.Parameter(p.clone()) for p in start]
    ref_opt = torch.optim.AdamW(ref, lr=1e-2, weight_decay=0.1)
    run(ref_opt, ref, range(6))
    old = [torch.nn.Parameter(p.clone()) for p in start]
    old_opt = torch.optim.AdamW(old, lr=1e-2, weight_decay=0.1)  # per-tensor, as saved before
    run(old_opt, old, range(3))
    new = [torch.nn.Parameter(p.detach().clone()) for p in old]
    opt = make_optimizer("adamw", new, lr=1e-2, weight_decay=0.1)
    assert opt.param_groups[0]["fused"]
    opt.load_state_dict(old_opt.state_dict())
    assert not opt.param_groups[0]["fused"]  # the saved group's flag
    use_fused_adamw(opt)
    assert opt.param_groups[0]["fused"]
    run(opt, new, range(3, 6))
    for a, b in zip(new, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
        assert not torch.equal(a, torch.zeros_like(a))


@pytest.fixture(scope="module")
def trained(episodes, tmp_path_factory) -> Path:
    """A 2-step abm run of ``_cfg`` (one checkpoint, at step 2), trained once for the module."""
    out = tmp_path_factory.mktemp("trained") / "run"
    train(_cfg(out, steps=2), episodes)
    return out


@pytest.fixture
def abm_run(trained, tmp_path) -> Path:
    """This test's own copy of the module's trained abm run, in ``tmp_path`` itself."""
    shutil.copytree(trained, tmp_path, dirs_exist_ok=True)
    return tmp_path


def test_resume_into_another_variant_is_a_clear_error(episodes, abm_run) -> None:
    tmp_path = abm_run
    with pytest.raises(ValueError, match="variant 'abm' but the model is 'rvt'"):
        train(_cfg(tmp_path, method="rvt", steps=2, resume=True), episodes)
    with pytest.raises(ValueError, match="expected 'rvt'"):
        KeyframePolicy.from_checkpoint(tmp_path, expect_variant="rvt")


def test_policy_load_and_act(episodes, abm_run) -> None:
    tmp_path = abm_run  # trained for 2 steps
    policy = KeyframePolicy.from_checkpoint(tmp_path)
    assert not policy.training
    obs, _ = episodes[0].steps[0]
    action = policy.act(obs, episodes[0].instruction, episodes[0].object_names)
    assert isinstance(action, KeyframeAction)
    assert policy.renderer.workspace.contains(action.position)
    assert set(policy.last_timings) == {"condition_s", "render_s", "model_s", "decode_s"}
    # acting on one observation = predicting on the dataset's sample of it (one pipeline, not two)
    ds = KeyframeDataset(episodes[:1], policy.workspace, **policy.sample_options(), augment=False)
    [predicted] = policy.predict(collate([ds[0]]))
    np.testing.assert_allclose(predicted.position, action.position, atol=1e-6)
    np.testing.assert_allclose(np.abs(predicted.quaternion @ action.quaternion), 1.0, atol=1e-6)
    # save / from_checkpoint round trip
    saved = policy.save(tmp_path / "exported.pt")
    again = KeyframePolicy.from_checkpoint(saved)
    np.testing.assert_allclose(again.act(obs, episodes[0].instruction, episodes[0].object_names).position,
                               action.position, atol=1e-6)
    with pytest.raises(ValueError, match="object_names"):
        policy.act(obs, episodes[0].instruction)
    # explain = act plus what the network saw and where it looked
    seen = policy.explain(obs, episodes[0].instruction, episodes[0].object_names)
    np.testing.assert_allclose(seen.action.position, action.position, atol=1e-6)
    v, r = policy.renderer.num_views, policy.renderer.resolution
    assert seen.view_rgb.shape == (v, r, r, 3) and seen.heatmaps.shape == seen.view_occupied.shape == (v, r, r)
    np.testing.assert_allclose(seen.heatmaps.reshape(v, -1).sum(-1), 1.0, atol=1e-4)
    assert seen.view_mask is not None and seen.view_mask.shape == (v, r, r)
    assert 0 < seen.view_occupied.mean() < 1
    # the predicted point projects onto each view's heatmap mode only approximately; it must be in-frame
    uv, _ = policy.renderer.project(torch.as_tensor(seen.action.position, dtype=torch.float32))
    assert ((uv >= -0.5) & (uv <= r - 0.5)).all()


def test_grounder_override_of_the_same_kind_keeps_trained_options(abm_run) -> None:
    tmp_path = abm_run
    (_, path), = list_checkpoints(tmp_path)
    ckpt = torch.load(path, weights_only=True)
    ckpt["grounder"] = {"kind": "clip", "model": "tiny", "threshold": 0.7}  # as if trained with a CLIP grounder
    torch.save(ckpt, path)
    merged = KeyframePolicy.from_checkpoint(tmp_path, grounder={"kind": "clip", "threshold": 0.5})
    assert merged.grounder_spec == {"kind": "clip", "model": "tiny", "threshold": 0.5}
    assert merged.grounder_config == ClipGrounderConfig(model="tiny", threshold=0.5)  # typed
    replaced = KeyframePolicy.from_checkpoint(tmp_path, grounder={"kind": "oracle"})
    assert replaced.grounder_spec == {"kind": "oracle"}
    typed = KeyframePolicy.from_checkpoint(tmp_path, grounder=ClipGrounderConfig(threshold=0.5))  # same as the dict
    assert typed.grounder_config == merged.grounder_config


def test_cli_errors(tmp_path, capsys) -> None:
    assert cli_main(["train", "--method", "abm", "--steps", "1", "--out", str(tmp_path)]) == 2
    assert "--data" in capsys.readouterr().err
    args = ["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "1",
            "--batch", "1", "--out", str(tmp_path), "--no-progress"]
    for key, value in TINY.items():
        args += ["--set", f"{key}={value}"]
    assert cli_main(args) == 0
    bad = [a if a != "abm" else "concat-full" for a in args] + ["--resume"]
    assert cli_main(bad) == 2
    assert "variant 'abm' but the model is 'concat-full'" in capsys.readouterr().err


def test_train_from_an_episode_store(episodes, tmp_path) -> None:
    from abm.data.episode_store import save_episode

    for i, ep in enumerate(episodes[:2]):
        save_episode(ep, tmp_path / "data" / f"ep{i}.h5")
    args = ["train", "--method", "concat-full", "--data", str(tmp_path / "data"), "--tasks", "pick_block",
            "--steps", "1", "--batch", "2", "--out", str(tmp_path / "run"), "--no-progress"]
    for key, value in TINY.items():
        args += ["--set", f"{key}={value}"]
    assert cli_main(args) == 0
    assert json.loads((tmp_path / "run/summary.json").read_text())["steps"] == 1
    other = [("close_jar" if a == "pick_block" else str(tmp_path / "run2") if a.endswith("run") else a)
             for a in args]
    assert cli_main(other) == 2  # no episode of that task: a clear error, not a crash


class _Payload:
    """Unpickling this calls ``Path.touch`` on the marker: what a crafted checkpoint could do."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        import pathlib

        return pathlib.Path.touch, (pathlib.Path(self.marker),)


def test_crafted_checkpoint_is_refused_without_running_code(episodes, tmp_path) -> None:
    from abm.policy.checkpoint import load_checkpoint

    train(_cfg(tmp_path / "run", steps=1, checkpoint_every=1), episodes)
    good = load_checkpoint(tmp_path / "run")  # a real checkpoint loads with weights_only=True
    assert good["step"] == 1
    marker = tmp_path / "pwned"
    bad = tmp_path / "evil.pt"
    torch.save({"format": "abm-policy", "version": 1, "x": _Payload(str(marker))}, bad)
    with pytest.raises(ValueError, match="refusing to load .*evil.pt.*crafted"):
        load_checkpoint(bad)
    assert not marker.exists()
    rc = cli_main(["eval", "--run", str(bad), "--tasks", "pick_block", "--split", "seen", "--episodes", "1",
                   "--repeats", "1", "--out", str(tmp_path / "ev")])
    assert rc != 0 and not marker.exists()


def test_an_existing_run_is_never_silently_replaced(episodes, tmp_path, capsys) -> None:
    train(_cfg(tmp_path / "run", steps=4), episodes)
    before = (tmp_path / "run/checkpoints/step_00000004.pt").read_bytes()
    with pytest.raises(ValueError, match=r"already holds a training run \(checkpoint at step 4\).*--resume"):
        train(_cfg(tmp_path / "run", method="rvt", steps=2), episodes)
    assert (tmp_path / "run/checkpoints/step_00000004.pt").read_bytes() == before
    assert json.loads((tmp_path / "run/config.json").read_text())["train"]["method"] == "abm"
    # resuming past the requested length is an error, and the run is left as it was
    with pytest.raises(ValueError, match="already at step 4, past --steps 2"):
        train(_cfg(tmp_path / "run", steps=2, resume=True), episodes)
    assert json.loads((tmp_path / "run/config.json").read_text())["train"]["steps"] == 4
    # resuming a finished run (the engine's carry of a model not exported yet) trains nothing more
    train(_cfg(tmp_path / "run", steps=4, resume=True), episodes)
    assert list_checkpoints(tmp_path / "run")[-1][0] == 4
    assert (tmp_path / "run/checkpoints/step_00000004.pt").read_bytes() == before
    # --overwrite replaces it: only the new run's checkpoints remain
    train(_cfg(tmp_path / "run", method="rvt", steps=2, overwrite=True), episodes)
    assert [s for s, _ in list_checkpoints(tmp_path / "run")] == [2]
    assert KeyframePolicy.from_checkpoint(tmp_path / "run").config.variant == "rvt"


def test_grounding_is_an_explicit_cached_step(episodes, tmp_path, capsys) -> None:
    """`abm data ground` fills the cache a CLIP-grounded training run reads; training finds it complete."""
    from abm.data.episode_store import save_episode

    data = tmp_path / "data"
    for i, ep in enumerate(episodes):
        save_episode(ep, data / f"ep{i}.h5")
    args = ["data", "ground", "--data", str(data), "--cache", str(tmp_path / "cache"), "--clip-model", "tiny",
            "--clip-device", "cpu"]
    assert cli_main(args) == 0
    assert "mask fields of 6 keyframes computed (3 episodes)" in capsys.readouterr().out
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 6
    assert cli_main(args) == 0
    assert "of 0 keyframes computed" in capsys.readouterr().out  # resumable: nothing left to do
    summary = train(_cfg(tmp_path / "run", steps=1, data=data,
                         grounder={"kind": "clip", "model": "tiny", "device": "cpu"}, cache_dir=tmp_path / "cache",
                         policy={**TINY, "lang_dim": 512}, language="hash"))
    assert summary["steps"] == 1
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 6  # training used the entries made above


def test_overwrite_with_bad_options_keeps_the_old_run(episodes, abm_run) -> None:
    tmp_path = abm_run
    before = list_checkpoints(tmp_path)
    with pytest.raises(ValueError, match="use --grounder clip"):
        train(_cfg(tmp_path, steps=1, method="ifd", overwrite=True), episodes)
    with pytest.raises(ValueError, match="outside the policy's workspace cube"):
        train(_cfg(tmp_path, steps=1, overwrite=True, policy={**TINY, "workspace_size": 0.05}), episodes)
    assert list_checkpoints(tmp_path) == before  # nothing was deleted: the options were checked first


def test_export_drops_training_state_and_loads_like_a_checkpoint(episodes, tmp_path, trained) -> None:
    shutil.copytree(trained, tmp_path / "run")  # trained for 2 steps
    obs, _ = episodes[0].steps[0]
    args = (obs, episodes[0].instruction, episodes[0].object_names)
    reference = KeyframePolicy.from_checkpoint(tmp_path / "run").act(*args)
    [(_, ckpt)] = list_checkpoints(tmp_path / "run")
    assert cli_main(["export", "--run", str(tmp_path / "run"), "--out", str(tmp_path / "fp32.pt")]) == 0
    assert cli_main(["export", "--run", str(ckpt), "--out", str(tmp_path / "bf16.pt"), "--dtype", "bfloat16"]) == 0
    full, fp32, bf16 = (p.stat().st_size for p in (ckpt, tmp_path / "fp32.pt", tmp_path / "bf16.pt"))
    assert bf16 < 0.6 * fp32 < 0.6 * full  # no optimizer moments; then half-size weights
    data = torch.load(tmp_path / "bf16.pt", weights_only=True)
    assert not {"optimizer", "scheduler", "rng"} & set(data)
    assert data["exported_dtype"] == "bfloat16"
    assert all(v.dtype == torch.bfloat16 for v in data["model"].values() if v.is_floating_point())
    exact = KeyframePolicy.from_checkpoint(tmp_path / "fp32.pt").act(*args)
    np.testing.assert_allclose(exact.position, reference.position, atol=1e-6)
    half = KeyframePolicy.from_checkpoint(tmp_path / "bf16.pt")
    assert all(p.dtype == torch.float32 for p in half.parameters())
    assert half.renderer.workspace.contains(half.act(*args).position)
