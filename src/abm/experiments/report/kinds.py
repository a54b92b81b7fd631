"""The report's section kinds: the registry :data:`SECTIONS` (light: a spec is checked against it without importing
a writer).

A section kind is one :class:`SectionKind` entry: the keys a spec's section of that kind takes (besides ``kind``
and ``only``, :class:`abm.experiments.spec.Section`'s fields), its writer as ``"module:function"``, imported when a
report is written (:func:`abm.registry.resolve`), and whether its tables call for the line that says how to
reproduce them. A writer is ``write(ctx, section) -> list[str]``: the section's paragraphs (markdown blocks; empty
ones are left out) from the :class:`~abm.experiments.report.context.Context` (the spec, its outcomes, the layout).

**Adding a section kind**: its module in :mod:`abm.experiments.report.sections` (a ``write`` function) and its
:func:`register_section` entry here, plus its tests.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from abm.registry import Registry


@dataclass(frozen=True)
class SectionKind:
    """One section kind: an entry of :data:`SECTIONS`.

    Attributes:
        keys: the keys a section of this kind takes in a spec (besides ``kind`` and ``only``).
        description: one line: what it writes.
        writer: ``"module:function"`` of its writer (default: ``abm.experiments.report.sections.NAME:write``).
        reproduce: whether a table it writes is followed by the block's "Reproduce: ..." line (not for one that
            names its own command, or a headline at the top of a README, where the tables it sums up are linked).
    """

    keys: tuple[str, ...]
    description: str
    writer: str = ""
    reproduce: bool = True


#: every report section kind, by name (a spec section's ``kind``)
SECTIONS: Registry[SectionKind] = Registry("report section kind")


def register_section(name: str, kind: SectionKind) -> SectionKind:
    """Add a section kind to :data:`SECTIONS` (its writer by default ``abm.experiments.report.sections.NAME:write``)."""
    if not kind.writer:
        kind = replace(kind, writer=f"abm.experiments.report.sections.{name}:write")
    return SECTIONS.register(name, kind)


TABLE = ("title", "runs", "splits", "table", "paper")  # the keys of a success table
register_section("setup", SectionKind(
    ("show",), "one paragraph: machines, data, CLIP, recipe, training minutes and speed, stage times, evaluation"))
register_section("per_task", SectionKind(
    (*TABLE, "column", "spread"), "a table of the tasks (rows) by every run and split (columns), with averages"))
register_section("per_run", SectionKind(
    (*TABLE, "digits", "column", "spread"), "a table of the runs (rows) by the tasks of one split, with the average"))
register_section("averages", SectionKind(
    (*TABLE, "names", "column", "spread"), "a table of the runs' seen and unseen averages and their ratio"))
register_section("spread", SectionKind(
    ("of_table", "text"), "a sentence: the range of a table's averages beside the paper's"))
register_section("targets", SectionKind(
    ("text", "runs", "checks", "digits", "explain"), "each target checked against each row run's measurements"))
register_section("target_diagnosis", SectionKind(
    (), "what the diagnosis shows of each run that misses a target of an explaining targets section"))
register_section("headline", SectionKind(
    ("text", "runs", "splits", "paper", "names", "column", "digits", "of_table"),
    "the result in a paragraph (its differences held to a table's seed spread) and a small table, ours beside the "
    "paper's", reproduce=False))
register_section("caveats", SectionKind((), "the caveats of the runs that have cells"))
register_section("weakest_keyframes", SectionKind(
    ("splits",), "each run's keyframe kinds by position error, worst first"))
register_section("approach_yaw", SectionKind(
    ("splits", "task", "note"), "each run's rotation error at the approach keyframe against the grasp's"))
register_section("zoo_eval", SectionKind((), "the timed `abm zoo eval` and its table", reproduce=False))
register_section("text", SectionKind(("text",), "a paragraph of the spec's text"))
register_section("heading", SectionKind(("text",), "a heading"))
register_section("detail", SectionKind(("runs", "splits"), "every run on every task of the splits"))
register_section("keyframe_accuracy", SectionKind(
    ("splits", "text"), "per split: a heading, the weakest keyframes and the keyframe table of every diagnosis"))
register_section("figures", SectionKind((), "the spec's figures as markdown images"))
register_section("outcome_tables", SectionKind(("splits",), "per split, the tables `abm eval` wrote for every run"))
register_section("success_rows", SectionKind(
    ("title", "runs", "splits", "column", "describe", "digits"),
    "the runs and variants evaluated by every task and split, with averages"))
register_section("sentences", SectionKind(("sentences",), "comparison sentences of two rows' averages"))
register_section("missing", SectionKind(("text", "runs"), "the rows not evaluated"))
register_section("keyframe_rows", SectionKind(
    ("title", "kinds"), "final-checkpoint keyframe accuracy per method, task, split and kind"))
register_section("keyframe_curve", SectionKind(
    ("title", "kinds"), "a keyframe kind's position error against training steps"))
register_section("keyframe_compare", SectionKind(
    ("title", "runs", "names", "kinds"), "rotation / position error per task, split and kind, a column per run"))
register_section("grounding_quality", SectionKind(
    ("title", "source", "config"), "mask quality of one grounding configuration on the evaluated tasks"))
register_section("destination_grounding", SectionKind(
    ("title",), "the spec's CLIP grounder on each task's target and destination: IoU and hit rate per task and split",
    writer="abm.experiments.report.sections.grounding_quality:write_destination"))
register_section("seeds", SectionKind(
    ("title", "of_table", "seeds", "splits", "digits"), "the seed spread of a table, and the differences above it"))
register_section("editions", SectionKind(
    ("title", "runs", "splits", "earlier", "of_table", "names", "digits"),
    "each run's averages beside the same run's in the earlier editions' records, and the change"))
register_section("diagnosis", SectionKind(
    ("title", "runs", "splits", "kinds"),
    "per model: keyframe accuracy per kind, the skill-text probe and why its rollouts failed"))
register_section("loops", SectionKind(
    ("title", "runs", "splits", "column"), "episodes with a grasp <-> lift loop per row and split"))
# a probe's tables (abm.experiments.report.probe); no Reproduce line: the block's provenance names the command
PROBE = ("title", "runs", "source")
register_section("probe_fit", SectionKind(
    PROBE, "a probe's yaw fit on its training keyframes per step and arm (its records' fit rows)", reproduce=False))
register_section("probe_accuracy", SectionKind(
    PROBE, "a probe's keyframe accuracy per task, split and kind, a column per arm at its final step",
    reproduce=False))
register_section("probe_rollouts", SectionKind(
    PROBE, "a probe's rollout successes per task and split, a column per arm, with averages", reproduce=False))
register_section("skill_text_table", SectionKind(
    ("title", "source"), "one skill-text probe's table from its kept JSON", reproduce=False))
