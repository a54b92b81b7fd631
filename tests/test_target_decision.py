"""The arm never acts on a target it did not find: one decision (abm.grounding.decision) for ``abm run`` (replay,
dry-run and MuJoCo paths), ``abm ground --strict`` and the evaluation logs, and a confidence from every grounder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from abm.cli import main as cli_main
from abm.geometry import Workspace, fuse_cameras
from abm.grounding.decision import MIN_CONFIDENCE, GroundingRecorder, decide_target, target_candidates
from abm.grounding.grounders import ClipGrounder, OracleGrounder
from abm.grounding.mask_field import MaskField, MaskFieldConfig
from abm.grounding.tracking import TrackingGrounder
from abm.language.instruction import InstructionError
from abm.render.synthetic import synthetic_scene
from abm.robot import DryRunArm, MotionLimits, NoTargetError, ReplayCamera, record_observations, run_robot

# an untrained policy points anywhere in its 1 m workspace cube: limits that allow all of it
OPEN = MotionLimits(workspace_lower=(0.0, -0.5, -0.15), workspace_upper=(1.0, 0.5, 0.85), max_step_m=2.0,
                    max_tilt_deg=180.0)
OPEN_YAML = ("limits: {workspace_lower: [0, -0.5, -0.15], workspace_upper: [1, 0.5, 0.85], max_step_m: 2.0, "
             "max_tilt_deg: 180}\n")
PICK_BLOCK = ("blue block", "red block", "target", "yellow block")  # the scene of pick_block, seen, seed 0


@pytest.fixture(scope="module")
def recording(tmp_path_factory, expert_episode):
    """A pick_block expert episode (seen, seed 0, 48-pixel cameras) recorded as a replay folder."""
    episode = expert_episode("pick_block", "seen", 0, 48)
    assert tuple(sorted(set(episode.object_names.values()))) == PICK_BLOCK
    folder = tmp_path_factory.mktemp("rec")
    record_observations([obs for obs, _ in episode.steps], folder, episode.object_names, episode.instruction)
    return folder, episode


@pytest.fixture(scope="module")
def synthetic():
    """(observation, object names, fused cloud) of the synthetic scene: four blocks."""
    obs, names = synthetic_scene(seed=0, resolution=64)
    return obs, names, fuse_cameras(obs, Workspace())


def _lines(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# ---- the decision ------------------------------------------------------------------------------------------
def test_decision_refuses_absent_ambiguous_unfound_and_unsure_targets() -> None:
    names = {1: "red block", 2: "blue block", 3: "yellow block", 4: "target", 5: "yellow_block"}
    assert target_candidates("block", names) == ("blue block", "red block", "yellow block", "yellow_block")
    assert target_candidates("the Yellow-Block", names) == ("yellow block", "yellow_block")  # one name, twice
    assert target_candidates("gold block", names) == () and target_candidates("", names) == ()
    found = MaskField(np.array([0, 1, 1]), np.array([0.1, 0.9, 0.8]), True)
    assert found.confidence == pytest.approx(0.85)  # the mean heatmap over the mask
    ok = decide_target(found, "red block", names, grounder="clip")
    assert ok.found and ok.reason == "" and ok.candidates == ("red block",) and ok.confidence == pytest.approx(0.85)
    assert json.loads(json.dumps(ok.as_record()))["scene"] == ["blue block", "red block", "target", "yellow block",
                                                                 "yellow_block"]
    # a name the scene does not hold, even when the grounder marked something with confidence
    for absent in ("banana", "gold block"):
        refused = decide_target(found, absent, names)
        assert not refused.found and refused.confidence == 0.0 and refused.candidates == ()
        text = refused.message(f"put the {absent} on the target", "--allow-no-target")
        assert f"{absent!r} is not in the scene" in text and "the scene holds: blue block, red block" in text
        assert "candidates: none" in text and text.endswith("or pass --allow-no-target to act anyway")
    several = decide_target(found, "block", {1: "red block", 2: "blue block", 3: "target"})
    assert not several.found and several.candidates == ("blue block", "red block")
    assert "could be any of 2 objects" in several.reason and "name one of 'blue block', 'red block'" in \
        several.message("put the block on the target")
    # the grounder's own answer: not found (a fallback mask), empty, or unsure
    fallback = MaskField(np.array([0, 1, 1]), np.array([0.1, 0.3, 0.2]), False)
    assert fallback.confidence == 0.0
    refused = decide_target(fallback, "red block", names, grounder="clip")
    assert not refused.found and "the clip grounder did not find 'red block'" in refused.reason
    assert "2 point(s) it marked are only a fallback guess" in refused.reason
    assert not decide_target(MaskField(np.zeros(3), np.zeros(3), True), "red block", names).found
    unsure = MaskField(np.array([0, 1, 1]), np.array([0.0, 0.34, 0.34]), True)
    refused = decide_target(unsure, "red block", names)
    assert not refused.found and "not sure" in refused.reason and refused.confidence == pytest.approx(0.34)
    assert decide_target(unsure, "red block", names, min_confidence=0.3).found
    # a camera that names no objects: only the grounder's answer decides
    assert decide_target(found, "banana", None).found and not decide_target(unsure, "banana", {}).found
    assert "the camera names no objects" in decide_target(unsure, "banana", {}).message("x")
    assert not decide_target(found, "  ", names).found and decide_target(None, "red block", names).found
    with pytest.raises(ValueError, match="min_confidence"):
        decide_target(found, "red block", names, min_confidence=1.5)


def test_recorder_logs_the_decision_on_each_answer_and_restores_the_grounder(synthetic) -> None:
    obs, names, cloud = synthetic
    oracle = OracleGrounder()
    with GroundingRecorder(oracle) as grounding:
        assert grounding.record() is None  # not called yet (a policy variant without a mask)
        oracle.ground(obs, cloud, "purple elephant", names)
        oracle.ground(obs, cloud, "blue block", names)
        record = grounding.record()  # the latest answer's decision, as the evaluation logs store it
        assert record is not None and record["found"] and record["target"] == "blue block"
        assert record["confidence"] == 1.0 and record["grounder"] == "oracle" and grounding.last is None
    assert "ground" not in vars(oracle)  # the class's method again
    oracle.ground(obs, cloud, "blue block", names)
    assert grounding.last is None
    with GroundingRecorder(None) as nothing:  # a policy without a grounder
        assert nothing.record() is None


# ---- a confidence from every grounder ----------------------------------------------------------------------
def test_every_grounder_reports_a_confidence(synthetic, expert_episode, tmp_path, monkeypatch) -> None:
    pytest.importorskip("transformers")
    from abm.grounding.clip import tiny_clip

    obs, names, cloud = synthetic
    oracle = OracleGrounder()
    assert oracle.ground(obs, cloud, "blue block", names).confidence == 1.0
    assert oracle.ground(obs, cloud, "block", names).confidence == 0.0  # ambiguous name: nothing marked
    backbone = tiny_clip(seed=0)
    # the per-point field: the mean softmax probability over the masked points (threshold 0: every point)
    everything = MaskFieldConfig(threshold=0.0)
    field = ClipGrounder(backbone=backbone, mode="field", cache=tmp_path, config=everything).ground(
        obs, cloud, "blue block", names)
    assert field.found and field.mask.all() and 0.0 < field.confidence < 1.0
    assert field.confidence == pytest.approx(float(field.heatmap.mean()), rel=1e-5)
    fresh = ClipGrounder(backbone=backbone, mode="field", cache=tmp_path, config=everything)
    again = fresh.ground(obs, cloud, "blue block", names)
    assert again.confidence == pytest.approx(field.confidence) and fresh.backbone_calls == 0  # the disk cache
    strict = ClipGrounder(backbone=backbone, mode="field", config=MaskFieldConfig(threshold=1.0))
    assert strict.ground(obs, cloud, "blue block", names).confidence == 0.0  # not found: the fallback point
    raw = ClipGrounder(backbone=backbone, mode="field", config=MaskFieldConfig(normalization="raw", threshold=-1.0))
    assert raw.ground(obs, cloud, "blue block", names).confidence == 1.0  # cosines are no probability

    # proposals: the chosen candidate's probability among all candidates; k equal scores give 1/k
    def scores(equal: bool):
        def candidate_scores(self, observation, cloud, candidates, texts, feats):
            out = np.zeros((len(candidates), len(texts)))
            out[:, 0] = 0.3
            out[:, 1:] = 0.1  # every candidate looks more like the target than like "an object"
            if not equal:
                out[0, 0] += 10.0 / backbone.logit_scale  # one candidate e^10 times as likely as each other
            return out
        return candidate_scores

    proposals = ClipGrounder(backbone=backbone, mode="proposals")
    monkeypatch.setattr(ClipGrounder, "candidate_scores", scores(equal=True))
    tie = proposals.ground(obs, cloud, "block", names)
    k = int(round(1 / tie.confidence))
    assert tie.found and k >= 2 and tie.confidence == pytest.approx(1 / k)
    refused = decide_target(tie, "block", None, grounder="clip")  # a real camera: no names to compare
    assert not refused.found and "not sure which object is 'block'" in refused.reason
    monkeypatch.setattr(ClipGrounder, "candidate_scores", scores(equal=False))
    clear = ClipGrounder(backbone=backbone, mode="proposals").ground(obs, cloud, "block", names)
    assert clear.confidence > 0.99 and decide_target(clear, "block", None).found
    monkeypatch.undo()

    # tracking: the first answer's confidence, times the share of its points still found
    episode = expert_episode("pick_block", "seen", 0, 48)
    target, ep_names = episode.target_names[0], episode.object_names
    clouds = [(o, fuse_cameras(o, Workspace())) for o, _ in episode.steps[:3]]

    class Unsure:
        name = "unsure"

        def ground(self, observation, cloud, target, object_names=None) -> MaskField:
            answer = oracle.ground(observation, cloud, target, object_names)
            return MaskField(answer.mask, answer.heatmap, True, target, "", confidence=0.4)

    for inner, first in ((OracleGrounder(), 1.0), (Unsure(), 0.4)):
        tracker = TrackingGrounder(inner)
        confidences = [tracker.ground(o, c, target, ep_names).confidence for o, c in clouds]
        assert tracker.inner_calls == 1 and confidences[0] == pytest.approx(first)
        assert all(tracker.min_kept * first - 1e-6 <= v <= first + 1e-6 for v in confidences[1:]), confidences
    assert not decide_target(MaskField(np.ones(3), np.ones(3), True, confidence=0.4), target, ep_names).found


# ---- abm run ----------------------------------------------------------------------------------------------
class _GripperGuess:
    """Like CLIP's fallback: not found, yet marks the cloud points nearest the gripper (``found``/``confidence``
    as given)."""

    name = "guess"

    def __init__(self, found: bool = False, confidence: float | None = None) -> None:
        self.found, self.confidence = found, confidence

    def ground(self, observation, cloud, target, object_names=None) -> MaskField:
        dist = np.linalg.norm(cloud.xyz - np.asarray(observation.gripper_pose)[:3, 3], axis=1)
        mask = np.zeros(len(cloud), np.float32)
        mask[np.argsort(dist)[:5]] = 1.0
        return MaskField(mask, mask * 0.45, self.found, target, "", confidence=self.confidence)


def test_run_refuses_names_the_scene_does_not_hold_or_that_fit_several_objects(recording, shared_tiny_run,
                                                                               tmp_path) -> None:
    from abm.policy import KeyframePolicy

    folder, episode = recording
    policy = KeyframePolicy.from_checkpoint(shared_tiny_run)
    for instruction, candidates in (("put the banana on the target", []), ("put the gold block on the target", []),
                                    ("put the block on the target", ["blue block", "red block", "yellow block"])):
        camera = ReplayCamera(folder)
        arm = DryRunArm(*camera.recorded_gripper())
        log_dir = tmp_path / instruction.split()[2]
        with pytest.raises(NoTargetError, match="the scene holds: blue block, red block, target, yellow block") as err:
            run_robot(policy, camera, arm, instruction, OPEN, 2, log_dir)
        assert arm.commands == [] and err.value.decision.candidates == tuple(candidates)
        (line,) = _lines(log_dir / "steps.jsonl")  # refused before the first step: no keyframe predicted
        assert line["status"] == "refused" and line["grounding"]["candidates"] == candidates
        assert "--allow-no-target" in line["reason"] and not (log_dir / "step_000.npz").exists()
    # --allow-no-target is the explicit override: the run goes on, every step logs the refused decision
    arm = DryRunArm(*ReplayCamera(folder).recorded_gripper())
    records = run_robot(policy, ReplayCamera(folder), arm, "put the block on the target", OPEN, 1, tmp_path / "any",
                        allow_no_target=True)
    assert len(records) == len(arm.commands) == 1 and not records[0]["grounding"]["found"]
    # the recording's own instruction: found with confidence, logged with each step
    records = run_robot(policy, ReplayCamera(folder), arm, episode.instruction, OPEN, 1, tmp_path / "ok")
    assert records[0]["grounding"]["found"] and records[0]["grounding"]["confidence"] == 1.0


def test_run_refuses_a_mask_the_grounder_did_not_find_or_is_unsure_of(recording, shared_tiny_run, tmp_path,
                                                                      caplog) -> None:
    from abm.policy import KeyframePolicy

    folder, episode = recording
    cases = ((_GripperGuess(found=False), "the guess grounder did not find 'yellow block'; the 5 point(s)"),
             (_GripperGuess(found=True, confidence=0.3), "is not sure which object is 'yellow block' (confidence "
                                                         "0.30 < 0.50"),
             (TrackingGrounder(_GripperGuess(found=False)), "did not find 'yellow block'"))
    for grounder, reason in cases:
        policy = KeyframePolicy.from_checkpoint(shared_tiny_run, grounder=grounder)
        camera = ReplayCamera(folder)
        arm = DryRunArm(*camera.recorded_gripper())
        log_dir = tmp_path / "refused"
        with pytest.raises(NoTargetError, match="candidates: yellow block") as err:
            run_robot(policy, camera, arm, episode.instruction, OPEN, 2, log_dir)
        assert reason in str(err.value) and arm.commands == []
        (line,) = _lines(log_dir / "steps.jsonl")
        assert line["status"] == "refused" and line["grounding"]["found"] is False
        assert (log_dir / "step_000.npz").exists()  # what the policy saw, for review
    assert "ground" not in vars(grounder)  # the recorder put the grounder back
    records = run_robot(policy, ReplayCamera(folder), arm, episode.instruction, OPEN, 1, tmp_path / "anyway",
                        allow_no_target=True)
    assert len(arm.commands) == 1 and records[0]["grounding"]["reason"].startswith("the tracking grounder did not")
    assert "acting anyway" in caplog.text
    assert MIN_CONFIDENCE == 0.5


def test_abm_run_refuses_on_the_dry_run_replay_and_mujoco_paths(recording, shared_tiny_run, tmp_path,
                                                               cli_errors) -> None:
    folder, _ = recording
    replay = tmp_path / "replay.yaml"
    replay.write_text(f"cameras: {{kind: replay, path: {folder}}}\narm: {{kind: dry-run}}\n" + OPEN_YAML)
    sim = tmp_path / "sim.yaml"
    sim.write_text("arm: {kind: sim, task: pick_block, split: seen, seed: 0, resolution: 48}\n" + OPEN_YAML)
    for robot, extra, instruction, candidates in (
            (sim, ["--dry-run"], "put the gold block on the target", "candidates: none"),
            (replay, [], "put the block on the target", "candidates: blue block, red block, yellow block"),
            (sim, [], "put the banana on the target", "candidates: none")):
        log_dir = tmp_path / f"{robot.stem}{len(extra)}"
        base = ["run", "--robot", str(robot), "--run", str(shared_tiny_run), "--steps", "1", "--log", str(log_dir),
                "--instruction", instruction, *extra]
        assert cli_main(base) == 2
        (error,) = cli_errors()
        assert error.startswith(f"abm: error: refused before moving: no target to act on for {instruction!r}")
        assert "the scene holds: blue block, red block, target, yellow block" in error and candidates in error
        assert f"(log: {log_dir})" in error
    assert cli_main([*base, "--allow-no-target"]) == 0  # the MuJoCo arm moves when told to
    assert _lines(log_dir / "steps.jsonl")[0]["status"] in {"reached", "unreachable", "blocked", "collided"}


def test_an_empty_instruction_is_refused(recording, shared_tiny_run, tmp_path, cli_errors) -> None:
    from abm.policy import KeyframePolicy

    folder, episode = recording
    replay = tmp_path / "replay.yaml"
    replay.write_text(f"cameras: {{kind: replay, path: {folder}}}\narm: {{kind: dry-run}}\n" + OPEN_YAML)
    for text in ("", "   \t"):
        assert cli_main(["run", "--robot", str(replay), "--run", str(shared_tiny_run), "--instruction", text,
                         "--log", str(tmp_path / "log")]) == 2
        (error,) = cli_errors()
        assert error.startswith("abm: error: --instruction is empty;") and "leave the option out" in error
    assert not (tmp_path / "log").exists()  # nothing ran, not even the recording's instruction
    silent = tmp_path / "silent"
    record_observations([episode.steps[0][0]], silent, episode.object_names, instruction=" ")
    mute = tmp_path / "mute.yaml"
    mute.write_text(f"cameras: {{kind: replay, path: {silent}}}\narm: {{kind: dry-run}}\n")
    assert cli_main(["run", "--robot", str(mute), "--run", str(shared_tiny_run)]) == 2
    assert "give --instruction: the camera source of" in cli_errors()[0]
    policy = KeyframePolicy.from_checkpoint(shared_tiny_run)
    arm = DryRunArm(*ReplayCamera(folder).recorded_gripper())
    with pytest.raises(InstructionError, match="the instruction is empty"):
        run_robot(policy, ReplayCamera(folder), arm, " \n", OPEN, 1, tmp_path / "l")
    assert arm.commands == []


# ---- abm ground --strict ----------------------------------------------------------------------------------
def test_ground_strict_uses_the_same_decision(tmp_path, cli_errors) -> None:
    out = tmp_path / "g"
    args = ["ground", "--out", str(out), "--instruction", "put the block in the plate", "--resolution", "32"]
    assert cli_main(args) == 0  # a warning, the images marked
    summary = json.loads((out / "summary.json").read_text())
    decision = summary["decision"]
    assert not decision["found"] and "could be any of 4 objects" in decision["reason"]
    assert decision["candidates"] == ["blue block", "green block", "purple block", "yellow block"]
    assert cli_main([*args, "--strict"]) == 2
    (error,) = cli_errors()
    assert "no target to act on for 'put the block in the plate'" in error and "--strict" in error
    assert "candidates: blue block, green block, purple block, yellow block" in error
    assert cli_main(["ground", "--out", str(out), "--instruction", "put the blue block in the plate",
                     "--resolution", "32", "--strict"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["decision"]["found"] and summary["confidence"] == 1.0
