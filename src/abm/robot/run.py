"""The deployment loop: observe -> ground -> predict -> check limits -> move, logged step by step.

A robot is described by a YAML file (the kinds: :mod:`abm.robot.kinds`)::

    cameras: {kind: replay, path: recordings/demo}     # or {kind: sim}, or {kind: realsense, serials: [...],
                                                       #   calibration: calibration.yaml} (abm.robot.realsense)
    arm: {kind: dry-run}                               # or {kind: sim, task: pick_block, split: seen, seed: 0},
                                                       #   or {kind: ur, host: 192.168.1.10, ...} (abm.robot.ur)
    limits: {workspace_lower: [0.2, -0.45, -0.02], workspace_upper: [0.85, 0.45, 0.6],
             max_step_m: 0.6, max_tilt_deg: 90}

``kind: sim`` uses one MuJoCo scene as both camera and arm (``cameras: {kind: sim}`` then shares the
arm's scene). Every step writes a line to ``LOG/steps.jsonl`` (the predicted keyframe, the limit
check, the arm's status, timings) and ``LOG/step_XXX.npz`` (the camera images, the policy's five
virtual views and its mask channel), so a run can be reviewed afterwards.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from abm.errors import ConfigError, RefusedError
from abm.files import load_yaml
from abm.grounding.decision import GroundingRecorder, TargetDecision, decide_target, normalize_name
from abm.grounding.mask_field import MaskField
from abm.language.instruction import (
    InstructionError,
    MultiStepInstructionError,
    NotOneCommandError,
    decompose_instruction,
    require_instruction,
)
from abm.language.resolve import Resolution, UnresolvedInstructionError, resolve_instruction
from abm.language.roles import split_roles
from abm.registry import Registry, resolve
from abm.robot.devices import DryRunArm, ReplayCamera, SimRobot
from abm.robot.kinds import ARM_KINDS, CAMERA_KINDS, Arm, Camera, DeviceKind
from abm.robot.limits import LIMITS_SCHEMA, LimitError, MotionLimits
from abm.schema import Field, SchemaError, any_mapping, check_mapping
from abm.types import Observation

if TYPE_CHECKING:  # torch: the policy is built by the command
    from abm.policy import KeyframePolicy

log = logging.getLogger(__name__)


# The robot file's declared schema: its sections; each section's options per ``kind`` are its registry entry's
# (abm.robot.kinds.CAMERA_KINDS, ARM_KINDS).
ROBOT_SCHEMA = {"cameras": Field(any_mapping), "arm": Field(any_mapping), "limits": Field(any_mapping)}


def _check_kind(path: str | Path, section: str, data: dict[str, Any], kinds: Registry[DeviceKind]) -> dict[str, Any]:
    """A ``{kind: ..., options}`` section checked against the options of its kind."""
    if "kind" not in data:
        raise SchemaError(f"{path}: {section}: missing required key 'kind' (one of {list(kinds)})")
    kind = data["kind"]
    if not isinstance(kind, str) or kind not in kinds:
        raise SchemaError(f"{path}: {section}.kind: expected one of {list(kinds)}, got {kind!r}")
    options = {k: v for k, v in data.items() if k != "kind"}
    return {"kind": kind, **check_mapping(path, section, options, dict(kinds[kind].options))}


@dataclass
class RobotConfig:
    """The ``--robot`` YAML file: camera source, arm and motion limits (see module docstring)."""

    cameras: dict[str, Any] = field(default_factory=lambda: {"kind": "sim"})
    arm: dict[str, Any] = field(default_factory=lambda: {"kind": "dry-run"})
    limits: MotionLimits = field(default_factory=MotionLimits)

    @classmethod
    def load(cls, path: str | Path) -> RobotConfig:
        """Read and check a robot file against its declared schema (:data:`ROBOT_SCHEMA`, the options of its
        kinds in :data:`abm.robot.kinds.CAMERA_KINDS` and ``ARM_KINDS``, :data:`abm.robot.limits.LIMITS_SCHEMA`) before
        anything is built.

        Raises:
            ValueError: (:class:`abm.schema.SchemaError`) naming the file, the key and what is expected.
        """
        data = load_yaml(path, "robot file")
        if data is None:
            raise SchemaError(f"{path}: the robot file is empty; expected the sections {sorted(ROBOT_SCHEMA)} "
                              "(see abm.robot.run)")
        top = check_mapping(path, "", data, ROBOT_SCHEMA)
        cameras = _check_kind(path, "cameras", top.get("cameras", {"kind": "sim"}), CAMERA_KINDS)
        arm = _check_kind(path, "arm", top.get("arm", {"kind": "dry-run"}), ARM_KINDS)
        limits = check_mapping(path, "limits", top.get("limits", {}), LIMITS_SCHEMA)
        try:
            return cls(cameras, arm, MotionLimits(**limits))
        except ValueError as err:
            raise SchemaError(f"{path}: limits: {str(err).removeprefix('motion limits: ')}") from None

    def build(self, dry_run: bool = False) -> tuple[Camera, Arm]:
        """``(camera, arm)`` built by their kinds' builders (:mod:`abm.robot.kinds`); ``dry_run`` replaces the arm by
        :class:`DryRunArm`. Sections of a ``simulated`` kind share one :class:`SimRobot` (the scene)."""
        sim = None
        arm_kind = "dry-run" if dry_run else self.arm.get("kind", "dry-run")
        arm_sim = ARM_KINDS[arm_kind].simulated
        if arm_sim or CAMERA_KINDS[self.cameras["kind"]].simulated:
            # the scene's options: the camera section's, and the arm section's when it is the scene (also in a
            # dry run, where the scene is only the camera)
            arm_opts = self.arm if ARM_KINDS[self.arm.get("kind", "dry-run")].simulated else {}
            opts = {k: v for k, v in {**self.cameras, **arm_opts}.items() if k != "kind"}
            if "task" not in opts:
                raise ConfigError("a simulated camera or arm needs task: give it in the cameras or arm section "
                                  "(e.g. arm: {kind: sim, task: pick_block})")
            sim = SimRobot(**opts)
        camera = self.build_camera(sim)
        arm: Arm
        if arm_sim:
            assert sim is not None
            arm = sim
        elif arm_kind == "dry-run":
            arm = DryRunArm(*self._dry_run_start(camera))
        else:
            arm = resolve(ARM_KINDS[arm_kind].build)(self.arm, limits=self.limits)
        return camera, arm

    def build_camera(self, sim: SimRobot | None = None) -> Camera:
        """The camera source alone (``sim``: the scene a camera of a simulated kind shares with the arm)."""
        kind = CAMERA_KINDS[self.cameras["kind"]]
        if kind.simulated:
            if sim is None:
                raise ConfigError(f"cameras: kind {self.cameras['kind']} shares the arm's scene; use it with arm kind "
                                  f"{' or '.join(ARM_KINDS.names(simulated=True))} or dry-run")
            return sim
        camera: Camera = resolve(kind.build)(self.cameras)
        return camera

    def _dry_run_start(self, camera: Camera) -> tuple[np.ndarray, float]:
        """A dry-run arm's start state: the recording's, the simulator's, or the real arm's (built read only)."""
        if isinstance(camera, ReplayCamera):
            return camera.recorded_gripper()
        if isinstance(camera, Arm):  # a camera that is also the arm (the simulator)
            return camera.state()
        kind = ARM_KINDS[self.arm.get("kind", "dry-run")]
        if kind.build:
            real = resolve(kind.build)(self.arm, read_only=True)  # reads its state only: nothing can move
            try:
                pose, opening = real.state()
                return pose, opening
            finally:
                if hasattr(real, "close"):
                    real.close()
        real_arms = [name for name, entry in ARM_KINDS.items() if entry.build]
        raise ConfigError(f"a dry run on camera kind {self.cameras.get('kind')!r} needs the arm's start pose: "
                          f"configure the real arm (kind {' or '.join(real_arms)}; a dry run only reads its pose)")


class NoTargetError(RefusedError):
    """The instruction's target is not an object the grounder found with confidence (absent, ambiguous, not
    found or unsure; :func:`abm.grounding.decision.decide_target`), so the arm would act blind; nothing moved.

    Attributes:
        decision: the refused :class:`~abm.grounding.decision.TargetDecision`.
    """

    def __init__(self, message: str, decision: TargetDecision) -> None:
        super().__init__(message)
        self.decision = decision


OVERRIDE = "--allow-no-target"


def _target_note(instruction: str) -> str:
    """`` (target: X)`` for the log line of :func:`run_robot`, or ``""`` when the instruction does not split."""
    try:
        return f" (target: {decompose_instruction(instruction)[0]})"
    except (InstructionError, ValueError):
        return ""


def resolve_for_policy(instruction: str, names: dict[int, str] | None) -> tuple[str, Resolution | None]:
    """``(the instruction the policy gets, the resolution)``: an instruction in plain words resolved onto the scene's
    objects (:func:`abm.language.resolve.resolve_instruction`: "grab the yellow one" -> "put the yellow block on
    the target"), so the names are checked and grounded as the scene spells them.

    The instruction is kept as given when the camera names no objects (``(instruction, None)``), when the
    templates already read it as the resolved object and skill, and when the resolution is refused but the text
    names an object the old way (the check before the first step then says what the scene lacks).

    Raises:
        MultiStepInstructionError: several steps or objects.
        UnresolvedInstructionError: no object and skill of the scene fit, and the text names no object.
    """
    if not names:
        return instruction, None
    try:
        resolution = resolve_instruction(instruction, names)
    except MultiStepInstructionError:
        raise
    except UnresolvedInstructionError:
        if _named_targets(instruction, names):
            return instruction, None  # decide_target refuses the named object with the scene's list
        raise
    try:
        parsed = decompose_instruction(instruction)
    except InstructionError:
        parsed = None
    named = tuple(normalize_name(t) for t in _named_targets(instruction, names))
    same = parsed is not None and parsed[1] == resolution.skill and \
        named == tuple(normalize_name(t) for t in resolution.targets)
    return (instruction if same else resolution.canonical), resolution


def _named_targets(instruction: str, names: dict[int, str] | None) -> tuple[str, ...]:
    """The objects of the instruction's sub-goals (X, and Y for a two-target skill), or ``()`` when it does not
    split (the policy then raises its own error, or a variant that reads the whole instruction runs)."""
    try:
        return split_roles(instruction, names)[0]
    except MultiStepInstructionError:
        raise
    except ValueError:
        return ()


def _step_decision(recorder: GroundingRecorder, seen: Any, names: dict[int, str] | None) -> TargetDecision | None:
    """The decision on the mask the policy acted on this step (None for a policy variant without a mask)."""
    call = recorder.take()
    if call is not None:
        return call.decide()
    sample = seen.sample
    if "point_mask" not in sample:
        return None
    # a mask the recorder did not see (a grounder whose method cannot be wrapped): judged by its points alone
    mask = np.asarray(sample["point_mask"], np.float32)
    field = MaskField(mask, np.asarray(sample.get("point_heatmap", mask), np.float32), bool(mask.any()))
    return decide_target(field, seen.target, names)


def _refuse(out: Any, step: int, instruction: str, decision: TargetDecision) -> NoTargetError:
    """Log a refused step and the error to raise (nothing has moved)."""
    reason = decision.message(instruction, OVERRIDE) + "; nothing was moved"
    out.write(json.dumps({"step": step, "status": "refused", "reason": reason,
                          "grounding": decision.as_record()}) + "\n")
    out.flush()
    return NoTargetError(reason, decision)


def run_robot(policy: KeyframePolicy, camera: Camera, arm: Arm, instruction: str, limits: MotionLimits, steps: int,
              log_dir: str | Path, allow_no_target: bool = False) -> list[dict[str, Any]]:
    """Run the loop for ``steps`` keyframes (or until a simulated arm reports success).

    An instruction in plain words is first resolved onto the scene's objects (:func:`resolve_for_policy`; the
    policy gets the resolved text, ``steps.jsonl`` keeps the given one and the resolution under ``resolved``).
    Every step's grounding is judged by :func:`abm.grounding.decision.decide_target` (one line per step in
    ``steps.jsonl`` holds it under ``grounding``); before the first step, the objects the instruction names are
    checked against the scene's vocabulary (``camera.object_names``, when the camera names its objects).

    Args:
        instruction: the instruction (empty or whitespace-only is refused).
        allow_no_target: act even when the target is refused (the refusal is logged as a warning).

    Raises:
        InstructionError: the instruction is empty or whitespace-only, or names no object of the scene in words
            :func:`abm.language.resolve.resolve_instruction` can resolve (nothing is moved).
        NotOneCommandError: the instruction is not one positive command about one object (a negation, condition,
            alternative, exclusion or swapped roles; :mod:`abm.language.one_command`): one line quoting the words,
            logged as a refused step 0; nothing is moved.
        NoTargetError: the target is not one object of the scene that the grounder found with confidence (a name
            the scene does not hold, several candidates, not found, unsure; not ``allow_no_target``); nothing is
            moved (the step is logged).
        LimitError: a predicted keyframe violates ``limits``; the arm is not moved (the step is logged).
        KeyboardInterrupt: Ctrl-C during a motion; the arm's ``stop()`` is called first (the step is logged).
    """
    instruction = require_instruction(instruction)
    log_dir = Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    records: list[dict[str, Any]] = []
    names = getattr(camera, "object_names", None) or None
    given = instruction
    try:  # a negation, condition, choice or swapped roles: refused whole, logged, never read another way
        instruction, resolution = resolve_for_policy(given, names)
        targets = _named_targets(instruction, names)
    except NotOneCommandError as err:
        (log_dir / "steps.jsonl").write_text(json.dumps({"step": 0, "status": "refused", "reason": str(err)}) + "\n")
        raise
    note = _target_note(instruction)
    if instruction != given and resolution is not None:
        note = (f" (target: {resolution.target}; read as {instruction!r}, confidence {resolution.confidence:.2f}, "
                f"by {resolution.method})")
    log.info("abm run: %r%s, %d keyframe(s) at most, log in %s", given, note, steps, log_dir)
    policy.reset()
    with (log_dir / "steps.jsonl").open("w") as out:
        for name in targets:  # every sub-goal's object, before anything moves
            named = decide_target(None, name, names)
            if not named.found and not allow_no_target:
                raise _refuse(out, 0, given, named)
        # policy.grounder builds the grounder (CLIP) only now, once the names passed
        with GroundingRecorder(getattr(policy, "grounder", None)) as grounding:
            for k in range(steps):
                t0 = time.perf_counter()
                pose, opening = arm.state()
                obs = Observation(camera.read(), opening, pose, k)
                seen = policy.explain(obs, instruction, names)  # the action and what the policy saw, in one pass
                arrays: dict[str, np.ndarray] = {f"camera/{n}": f.rgb for n, f in obs.cameras.items()}
                arrays["views"] = seen.view_images[:, :3]
                if seen.view_mask is not None:
                    arrays["mask"] = seen.view_mask
                # numpy's stub reads **arrays as able to fill allow_pickle
                np.savez_compressed(log_dir / f"step_{k:03d}.npz", **arrays)  # type: ignore[arg-type]
                decision = _step_decision(grounding, seen, names)
                if decision is not None and not decision.found:
                    if not allow_no_target:
                        raise _refuse(out, k, given, decision)
                    log.warning("step %d: %s (%s: acting anyway)", k, decision.message(given), OVERRIDE)
                action = seen.action
                first: dict[str, Any] = {"instruction": given} if k == 0 else {}
                if k == 0 and resolution is not None:
                    first["resolved"] = resolution.as_record()
                record = {"step": k, **first,
                          "position": action.position.round(4).tolist(),
                          "quaternion": action.quaternion.round(4).tolist(), "gripper_open": action.gripper_open,
                          "ignore_collision": action.ignore_collision, "timings": policy.last_timings}
                if decision is not None:
                    record["grounding"] = decision.as_record()
                try:
                    limits.check(pose, action)
                except LimitError as err:
                    record.update(status="refused", reason=str(err))
                    out.write(json.dumps(record) + "\n")
                    raise
                try:
                    record["status"] = arm.move(action)
                except KeyboardInterrupt:  # Ctrl-C: stop the arm where it is, keep the log
                    if hasattr(arm, "stop"):
                        arm.stop()
                    record["status"] = "interrupted"
                    out.write(json.dumps(record) + "\n")
                    raise
                record["seconds"] = time.perf_counter() - t0
                if hasattr(arm, "success"):
                    record["success"] = bool(arm.success())
                out.write(json.dumps(record) + "\n")
                out.flush()
                records.append(record)
                log.info("step %d: %s -> %s", k, record["position"], record["status"])
                if record.get("success"):
                    break
    return records
