"""The ``diagnosis`` report section: per model: keyframe accuracy per kind, the skill-text probe and why its rollouts
failed."""

from __future__ import annotations

from collections.abc import Sequence

from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import kind_medians
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.spec import Section


def probe_result(ctx: Context, run: str, task: str) -> tuple[float, bool, list[str]] | None:
    """A skill-text probe of ``run`` on ``task``: (the own skill text's distance cm from the expert's keyframe,
    whether it is within the target, the other skill texts whose prediction stays within the target of the
    own text's: the ones the policy does not tell apart), or ``None`` before it ran."""
    probe = ctx.spec.diagnose.skill_text if ctx.spec.diagnose is not None else None
    found = ctx.outcomes.probes.get((run, task))
    if probe is None or found is None:
        return None
    own = next(r for r in found["rows"] if r["own"])
    same = [str(r["skill"]) for r in found["rows"] if not r["own"] and r["moved_cm_median"] < probe.within_cm]
    return float(own["position_cm_median"]), own["position_cm_median"] <= probe.within_cm, same


def failure_counts(ctx: Context, run: str, splits: Sequence[str] | None = None) -> dict[str, int]:
    """Failed rollouts of ``run`` by reason, summed over the tasks (and ``splits``; default all), most first."""
    total: dict[str, int] = {}
    for (name, _, split), rate in ctx.cells.items():
        if name == run and (splits is None or split in splits):
            for reason, n in (rate.get("failures") or {}).items():
                total[reason] = total.get(reason, 0) + int(n)
    return dict(sorted(total.items(), key=lambda kv: -kv[1]))


def diagnosis_summary(ctx: Context, run: str) -> str:
    """What the diagnosis shows of ``run``, in a sentence: the keyframe kinds with the largest position errors and
    those whose rotation is no better than a random yaw (seen objects), the skill-text probe, and why its
    rollouts failed."""
    parts = []
    kinds = kind_medians(ctx.outcomes.summaries.get(run, []), "seen")
    if kinds:
        worst = sorted(kinds.items(), key=lambda kv: -kv[1][0])[:2]
        parts.append("the largest keyframe errors (seen objects) at " + " and ".join(
            f"{kind} ({cm:.1f} cm, {deg:.0f}°)" for kind, (cm, deg, _) in worst))
        at_chance = [f"{kind} ({deg:.0f}° against {chance:g}°)" for kind, (_, deg, chance) in kinds.items()
                     if chance and deg >= 0.8 * chance]
        if at_chance:
            parts.append("a rotation no better than a random yaw's at " + ", ".join(at_chance))
    probe = ctx.spec.diagnose.skill_text if ctx.spec.diagnose is not None else None
    if probe is not None:
        results = [(task, r) for task in probe.tasks if (r := probe_result(ctx, run, task)) is not None]
        if results:
            parts.append(f"the skill-text probe at the {probe.kind} keyframe: " + ", ".join(
                f"{task}'s own text {cm:.1f} cm from the expert's ({'within' if ok else 'not within'} "
                f"{probe.within_cm:g} cm)" for task, (cm, ok, _) in results))
    failures = failure_counts(ctx, run)
    if failures:
        parts.append("its failed rollouts: " + ", ".join(f"{reason} {n}" for reason, n in failures.items()))
    return "; ".join(parts) if parts else "no diagnosis of it yet"


def write(ctx: Context, section: Section) -> list[str]:
    """Per model: keyframe accuracy per kind beside a random yaw's error, the skill-text probe, and the failure
    reasons of its rollouts."""
    runs = section.runs or tuple(ctx.spec.runs)
    out = [section.title] if section.title else []
    for split in section.splits or ("seen",):
        rows = {name: kind_medians(found, split) for name, found in ctx.outcomes.summaries.items()
                if name.split("@")[0] in runs}
        rows = {name: kinds for name, kinds in rows.items() if kinds}
        kinds = [k for k in dict.fromkeys(k for found in rows.values() for k in found)
                 if not section.kinds or k in section.kinds]
        if not rows or not kinds:
            continue
        lines = table_head(["model", *kinds])
        for name, found in rows.items():
            lines.append(table_row([name, *(f"{found[k][0]:.1f} / {found[k][1]:.0f}"
                                            + (f" ({found[k][2]:g})" if found[k][2] is not None else "")
                                            if k in found else "–" for k in kinds)]))
        out += [f"Keyframe accuracy per kind, {split} objects (the expert's rollouts, teacher-forced): the median "
                "over the tasks of the median position error (cm) / rotation error (°, symmetry-aware), in brackets "
                "a random yaw's error for the keyframe's symmetry (45° two-fold, 22.5° four-fold, 0 round): a "
                "rotation error near it is chance. RUN@oracle: fed the simulator's mask.", "\n".join(lines)]
    probe = ctx.spec.diagnose.skill_text if ctx.spec.diagnose is not None else None
    probed = [r for r in runs if probe is not None and r in probe.runs
              and any(probe_result(ctx, r, t) for t in probe.tasks)]
    if probe is not None and probed:
        lines = table_head(["model", *probe.tasks])
        for run in probed:
            cells = []
            for task in probe.tasks:
                result = probe_result(ctx, run, task)
                cells.append("–" if result is None else f"{result[0]:.1f} cm, {'met' if result[1] else 'not met'}"
                             f" ({len(result[2])} other text{'' if len(result[2]) == 1 else 's'} within "
                             f"{probe.within_cm:g} cm of it)")
            lines.append(table_row([run, *cells]))
        out += [f"Skill-text probe at the {probe.kind} keyframe ({probe.episodes} {probe.split} scenes per task, "
                "teacher-forced; `benchmarks/skill_text_probe.py`): how far (median, cm) the prediction with the "
                "scene's own skill text lands from the expert's destination, against the target of "
                f"{probe.within_cm:g} cm, and how many of the other tasks' skill texts, worded about the same "
                f"object, move it less than {probe.within_cm:g} cm (texts the policy does not tell apart):",
                "\n".join(lines)]
    splits = [s.split for s in ctx.spec.evaluation.splits]
    failed = [(run, split, counts) for run in runs for split in splits
              if (counts := failure_counts(ctx, run, [split]))]
    if failed:
        reasons = list(dict.fromkeys(reason for _, _, counts in failed for reason in counts))
        lines = table_head(["model", "split", "failed / episodes", *reasons])
        for run, split, counts in failed:
            episodes = sum(int(r["episodes"]) for (n, _, s), r in ctx.cells.items() if n == run and s == split)
            lines.append(table_row([run, split, f"{sum(counts.values())} / {episodes}",
                                    *(str(counts.get(reason, 0)) for reason in reasons)]))
        out += ["Why the rollouts failed (episodes per reason, summed over the tasks; per task in the records JSON): "
                "grasp missed: the gripper never held the target; timeout: it held it but the task was not done "
                "within the step limit; IK unreachable, motion blocked, collision: the arm could not follow a "
                "keyframe; crashed: the rollout raised.", "\n".join(lines)]
    return out
