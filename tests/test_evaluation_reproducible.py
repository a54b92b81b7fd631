"""An evaluation outcome is a function of (model file, task, split, seed, settings) alone: the same episode by
episode — success, steps, failure and the digest of every predicted keyframe — in process (``--workers 1``) in
a driver with several torch threads and GIFs on (acting through ``explain()``), and through ``abm zoo eval``
(two worker processes, each running both models' episodes) from a folder outside the checkout (the models name
their CLIP by a path relative to the checkout, ``models/benchmark-clip``).

Also: runs share a table row only when they are the same checkpoint file, a run that cannot load fails before
any rollout, and any crashed episode makes ``abm eval`` exit non-zero with the first error.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from abm.cli import main
from abm.evaluation.policies import checkpoint_clips, clip_root, load_policy, rollout_state
from abm.evaluation.results import EpisodeOutcome, OutcomeLog
from abm.evaluation.runner import EvalSettings, evaluate, method_labels
from abm.policy.checkpoint import load_checkpoint, save_checkpoint
from abm.zoo import COMPARED_METHODS, edition, pick, read_index

ZOO = Path(__file__).resolve().parents[1] / "models"
SETTINGS = EvalSettings(max_steps=3)


def _episodes(outcomes: list[EpisodeOutcome], checkpoint: str) -> dict[tuple[str, str, int, int], tuple[Any, ...]]:
    """(task, split, repeat, episode) -> what the rollout did, for one checkpoint's outcomes (the log names a
    checkpoint relative to the working folder when inside it, so the file name identifies it across folders)."""
    assert not [o.error for o in outcomes if o.error]
    return {(o.task, o.split, o.repeat, o.episode): (o.success, o.steps, o.failure, o.trajectory)
            for o in outcomes if Path(o.checkpoint).name == Path(checkpoint).name}


def test_outcomes_are_the_same_whatever_the_command_workers_gifs_or_working_folder(tmp_path, monkeypatch) -> None:
    from sim_helpers import require_simulator

    require_simulator()
    pytest.importorskip("transformers")
    if not (ZOO / "abm_clip.pt").is_file() or not (ZOO / "benchmark-clip" / "config.json").is_file():
        pytest.skip("the committed model zoo is not in this checkout")
    # the models abm zoo eval runs: of abm and rvt each the newest edition's compared one (earlier editions' stay
    # marked compared in the index)
    entries = read_index(ZOO)
    chosen = [pick(entries, method) for method in COMPARED_METHODS]
    models = [str((ZOO / e["file"]).resolve()) for e in chosen if e is not None]
    assert len(models) == 2 and all(e is not None and e["edition"] == max(edition(x) for x in entries) for e in chosen)

    threads = torch.get_num_threads()
    torch.set_num_threads(2)  # what a process gets by default on a 2-core machine (pool workers run 1)
    try:  # abm eval --workers 1 --gifs 1: in process, acting through explain()
        alone: list[EpisodeOutcome] = []
        evaluate(models, ["close_jar"], "seen", tmp_path / "alone", episodes=1, repeats=1, workers=1,
                 settings=SETTINGS, gifs=1, progress=False, collect=alone)
        assert torch.get_num_threads() == 2  # the caller's thread count is given back
    finally:
        torch.set_num_threads(threads)
    assert len(list((tmp_path / "alone" / "gifs").glob("*.gif"))) == 2

    # abm zoo eval: two worker processes running both models' episodes, from outside the checkout
    monkeypatch.chdir(tmp_path)
    assert main(["zoo", "eval", "--zoo", str(ZOO), "--tasks", "close_jar", "--episodes", "1", "--max-steps", "3",
                 "--workers", "2", "--out", "zoo"]) == 0
    zoo = OutcomeLog(tmp_path / "zoo" / "seen" / "outcomes.jsonl").read()
    assert {o.checkpoint for o in zoo} == set(models)
    for model in models:
        reference = _episodes(alone, model)
        assert len(reference) == 1 and all(len(r[3]) == 16 for r in reference.values())
        assert _episodes(zoo, model) == reference, model


def test_a_zoo_moved_out_of_its_layout_fails_before_any_rollout(tmp_path, capsys, monkeypatch) -> None:
    if not (ZOO / "index.json").is_file() or not (ZOO / "benchmark-clip" / "config.json").is_file():
        pytest.skip("the committed model zoo is not in this checkout")
    moved = tmp_path / "elsewhere"  # not named models/: the models' CLIP path models/benchmark-clip finds nothing
    moved.mkdir()
    index = json.loads((ZOO / "index.json").read_text())
    for name in ["index.json", *(e["file"] for e in index if e["file"].endswith(".pt"))]:
        shutil.copy(ZOO / name, moved / name)
    compared = [e["file"] for e in index if e.get("compared")]  # the models abm zoo eval loads
    shutil.copytree(ZOO / "benchmark-clip", moved / "benchmark-clip")
    monkeypatch.chdir(tmp_path)
    assert main(["zoo", "eval", "--zoo", str(moved), "--tasks", "close_jar", "--episodes", "1", "--out", "o"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("abm: error: ")
    assert any(f"{file} names its CLIP 'models/benchmark-clip', which is not found" in err[0] for file in compared)
    assert "folder named 'models'" in err[0] and "--zoo" in err[0]
    assert not (tmp_path / "o").exists()  # nothing was rolled out


def test_relative_clip_paths_resolve_from_the_model_folder_upwards(tmp_path, tiny_run, monkeypatch) -> None:
    project = tmp_path / "project"
    (project / "clips" / "mine").mkdir(parents=True)
    (project / "clips" / "mine" / "config.json").write_text("{}")
    ckpt = load_checkpoint(tiny_run)
    ckpt["grounder"] = {"kind": "tracking", "inner": {"kind": "clip", "model": "clips/mine"}}
    model = save_checkpoint(project / "models" / "deep" / "x.pt", ckpt)
    monkeypatch.chdir(tmp_path)
    assert clip_root(model, ["clips/mine"]) == project
    assert clip_root(model, ["tiny", "/abs/clip"]) is None  # test CLIPs and absolute paths need no root
    assert checkpoint_clips(model) == {"clips/mine": (project / "clips" / "mine").resolve()}
    (project / "clips" / "mine" / "config.json").unlink()
    assert checkpoint_clips(model) == {"clips/mine": None}


def test_every_rollout_gets_a_fresh_policy_one_thread_and_seeded_rngs(tiny_run) -> None:
    first = load_policy(tiny_run, EvalSettings())
    tokens = first.encode_language(["pick up the red block"])  # fills the language cache the copies share
    second = load_policy(tiny_run, EvalSettings())
    assert second is not first
    assert all(a.data_ptr() != b.data_ptr() for a, b in zip(first.parameters(), second.parameters(), strict=True))
    assert "pick up the red block" in second._lang_cache  # remembered, not recomputed: the same tokens
    assert torch.equal(second.encode_language(["pick up the red block"]), tokens)
    threads = torch.get_num_threads()
    before = torch.random.get_rng_state()
    with rollout_state(7):
        assert torch.get_num_threads() == 1
        draw = torch.rand(3)
    with rollout_state(7):
        assert torch.equal(torch.rand(3), draw)
    assert torch.get_num_threads() == threads and torch.equal(torch.random.get_rng_state(), before)


def test_copies_and_policies_grounding_with_one_clip_share_its_exact_memories(tiny_run, tmp_path) -> None:
    from abm.evaluation.policies import clip_grounders, forget_policies
    from abm.train.synthetic import synthetic_episodes

    other = tmp_path / "other"  # another model grounding with the same CLIP
    shutil.copytree(tiny_run, other)
    settings = EvalSettings(grounder="clip", clip_model="tiny")
    forget_policies()
    try:
        first, again, second = load_policy(tiny_run, settings), load_policy(tiny_run, settings), load_policy(
            other, settings)
        (g1,), (g2,), (g3,) = (clip_grounders(p.grounder) for p in (first, again, second))
        assert g1 is not g2 and next(first.parameters()) is not next(again.parameters())
        assert all(a is b for a, b in zip(g1.exact_memories(), g2.exact_memories(), strict=True))
        assert all(a is b for a, b in zip(g1.exact_memories()[1:], g3.exact_memories()[1:], strict=True))
        assert g1.backbone is not g3.backbone  # each model loads its CLIP; the memories are one
        assert _same_objects(first.exact_memories(), (first._lang_cache, *g1.exact_memories()))

        episode = synthetic_episodes(1, camera_resolution=32)[0]
        obs = episode.steps[0][0]
        act = (obs, episode.instruction, episode.object_names)
        shared = first.act(*act).matrix, second.act(*act).matrix
        assert g1.backbone_calls > 0 and g3.backbone_calls == 0  # the second model grounded from memory
        forget_policies()  # a process that loads only the other model: nothing remembered
        alone = load_policy(other, settings)
        assert np.array_equal(alone.act(*act).matrix, shared[1]) and np.array_equal(shared[0], shared[1])
        assert clip_grounders(alone.grounder)[0].backbone_calls > 0
    finally:
        forget_policies()


def test_a_tracking_grounders_copies_share_the_memories_of_the_clip_it_wraps(tiny_run) -> None:
    from abm.evaluation.policies import clip_grounders, forget_policies

    settings = EvalSettings(grounder="tracking", clip_model="tiny")
    forget_policies()
    try:
        first, again = load_policy(tiny_run, settings), load_policy(tiny_run, settings)
        assert first.grounder is not again.grounder  # each rollout tracks its own target
        (inner,), (inner_again,) = clip_grounders(first.grounder), clip_grounders(again.grounder)
        assert inner is not inner_again and inner.backbone is inner_again.backbone
        assert _same_objects(first.exact_memories(), (first._lang_cache, *inner.exact_memories()))
    finally:
        forget_policies()


def test_an_oracle_policy_shares_only_its_language_tokens(tiny_run) -> None:
    from abm.policy import KeyframePolicy

    policy = KeyframePolicy.from_checkpoint(next((tiny_run / "checkpoints").glob("*.pt")))
    assert _same_objects(policy.exact_memories(), (policy._lang_cache,))  # the grounder is not built yet
    policy.grounder  # noqa: B018 - builds the oracle, which remembers nothing
    assert _same_objects(policy.exact_memories(), (policy._lang_cache,))


def _same_objects(a: tuple[object, ...], b: tuple[object, ...]) -> bool:
    return len(a) == len(b) and all(x is y for x, y in zip(a, b, strict=True))


def _fake_runner(job: Any, settings: EvalSettings) -> EpisodeOutcome:
    return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed, job.episode == 0,
                          checkpoint=job.checkpoint, settings=job.settings)


def test_runs_share_a_table_row_only_when_they_are_the_same_file(tmp_path, tiny_run) -> None:
    a, b = tmp_path / "a" / "run", tmp_path / "b" / "run"  # same variant, same folder name, two files
    shutil.copytree(tiny_run, a)
    shutil.copytree(tiny_run, b)
    ckpt_a = next((a / "checkpoints").glob("*.pt"))
    labels = method_labels([a, b])
    assert labels == {str(a): "abm (a/run)", str(b): "abm (b/run)"}
    rates = evaluate([a, b, ckpt_a], ["pick_block"], "seen", tmp_path / "ev", episodes=2, repeats=1,
                     progress=False, runner=_fake_runner)  # ckpt_a is run a again: evaluated once
    assert sorted((r.method, r.episodes) for r in rates) == [("abm (a/run)", 2), ("abm (b/run)", 2)]
    with pytest.raises(ValueError, match="same table label 'abm'.*pooled into one row"):
        evaluate([a, b], ["pick_block"], "seen", tmp_path / "ev2", episodes=1, repeats=1, progress=False,
                 runner=_fake_runner, labels={str(a): "abm", str(b): "abm"})


def test_a_crash_fails_the_command_and_a_policy_that_cannot_load_fails_before_any_rollout(
        tmp_path, tiny_run, capsys, monkeypatch, cli_errors) -> None:
    from abm.sim import env as sim_env

    pytest.importorskip("mujoco")
    real = sim_env.make_env

    def make_env(task: str, split: str, seed: int, *args: Any, **kwargs: Any) -> Any:
        if seed % 2:  # episode 1 of each repeat
            raise RuntimeError(f"scene {seed} exploded")
        return real(task, split, seed, *args, **kwargs)

    monkeypatch.setattr(sim_env, "make_env", make_env)
    base = ["eval", "--run", str(tiny_run), "--tasks", "pick_block", "--split", "seen", "--episodes", "2",
            "--repeats", "1", "--max-steps", "1", "--resolution", "32", "--workers", "1"]
    assert main([*base, "--out", str(tmp_path / "ev")]) == 2
    captured = capsys.readouterr()
    assert "| abm |" in captured.out and "Traceback" not in captured.err  # the table is still written and shown
    [line] = [s for s in captured.err.splitlines() if s.startswith("abm: error: ")]
    assert "1 of 2 episode(s) crashed" in line
    assert "episode 1 (seed 1000001): RuntimeError: scene 1000001 exploded" in line
    assert "run the same command again" in line
    outcomes = [json.loads(s) for s in (tmp_path / "ev" / "outcomes.jsonl").read_text().splitlines()]
    assert [bool(o["error"]) for o in sorted(outcomes, key=lambda o: o["episode"])] == [False, True]

    ckpt = load_checkpoint(tiny_run)  # a model naming a CLIP folder that is nowhere
    ckpt["grounder"] = {"kind": "clip", "model": "nowhere/clip"}
    broken = save_checkpoint(tmp_path / "m" / "broken.pt", ckpt)
    assert main([*base[:2], str(broken), *base[3:], "--out", str(tmp_path / "ev2")]) == 2
    [line] = cli_errors()
    assert f"cannot load the policy {broken}: its CLIP nowhere/clip" in line and "put the CLIP folder" in line
    assert not (tmp_path / "ev2" / "outcomes.jsonl").exists()
