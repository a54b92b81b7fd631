"""Every generated block of an experiment, from its spec and its outcomes (never typed by hand).

:func:`~abm.experiments.report.files.write_report` reads the outcomes of an experiment (OUT after
:func:`abm.experiments.state.restore`, so the committed ones count) and writes

* the document (``report.document``, e.g. ``docs/results/paper_tables.md``): the summary sections, then the
  detail sections;
* the README block between ``<!-- BLOCK:start -->`` and ``<!-- BLOCK:end -->`` (the summary sections and a
  link to the document), and the further blocks of ``report.blocks`` in the same README (e.g. a headline);
  with a README gate (``report.readme_when``, :mod:`~abm.experiments.report.gate`), only once the tables it
  names are complete, as the zoo's README below;
* the records (``report.records``, e.g. ``docs/results/paper_tables.json``): one record per (table, run,
  task, split) cell with ``successes`` and ``episodes`` (plus mean, std and per-repeat rates);
* the zoo's index and README (``ZOO/index.json``, ``ZOO/README.md``) when the spec exports into a zoo:
  every exported model (method, grounding, recipe, data, steps, minutes, size, sha256) and the benchmark CLIP;
  the entries other specs exported into the same zoo (an earlier or later edition's) are kept as they are, and
  the zoo's README is written by the newest edition's spec;
* the run summaries (``KEPT/runs.json``) of an experiment without a zoo, every run's compact loss curve
  (``KEPT/training_RUN.csv``, also kept when a run is exported), and the figures (``report.figures``), drawn from
  the kept files only.

A report is a list of paragraphs (blocks) joined by blank lines; each section of the spec adds zero or more, written
by its kind's writer: the section kinds are the registry :data:`~abm.experiments.report.kinds.SECTIONS` (each kind's
keys and its writer, one module per kind in :mod:`abm.experiments.report.sections`). A section marked ``only:
document`` (or ``readme``) is left out of the other. Cells not evaluated yet show "–", so tables fill in stages (the
first line says so while one does). Links in the summary are written relative to the repository root (the README's
folder) and rewritten relative to the document's folder in the document.

The modules: :mod:`~abm.experiments.report.outcomes` (what a report is written from), ``runs`` (what a run
folder tells), ``numbers`` (cells and averages), ``context`` (what a section writer sees), ``keyframes`` (the
keyframe diagnosis as the report reads it), ``kinds`` and ``sections`` (the section kinds), ``texts`` (the texts,
:func:`~abm.experiments.report.texts.compose`), ``gate`` (when the README's blocks and the zoo's README are
written) and ``files`` (writing them, only into files the report owns).
"""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; each is imported on first use (abm.lazy), so that abm.experiments.spec can read
    # the section kinds (abm.experiments.report.kinds) without importing the writers, which import the spec
    from abm.experiments.report.context import Context
    from abm.experiments.report.files import (
        NotOwnedError,
        block_of,
        check_owned,
        draw_figures,
        keep_training_log,
        replace_block,
        report_files,
        write_report,
    )
    from abm.experiments.report.gate import held_back, status_line, waits
    from abm.experiments.report.keyframes import approach_yaw, keyframe_table, kind_medians, weakest_keyframes
    from abm.experiments.report.numbers import Cells, average, standard_error
    from abm.experiments.report.outcomes import (
        Outcomes,
        collect,
        collect_cells,
        kept_run_summaries,
        keyframe_summaries,
        skill_text_probes,
        zoo_index,
    )
    from abm.experiments.report.runs import describe_run, training_summary
    from abm.experiments.report.sections.seeds import seed_spread
    from abm.experiments.report.texts import (
        Written,
        blocks,
        compose,
        newest_edition,
        provenance,
        records,
        relink,
        shows_dash,
        spec_name,
        write_section,
        zoo_readme,
    )

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = ["Cells", "Context", "NotOwnedError", "Outcomes", "Written", "approach_yaw", "average", "block_of", "blocks",
           "check_owned", "collect", "collect_cells", "compose", "describe_run", "draw_figures", "held_back",
           "keep_training_log", "keyframe_summaries", "keyframe_table", "kept_run_summaries", "kind_medians",
           "newest_edition", "provenance", "records", "relink", "replace_block", "report_files",
           "seed_spread", "shows_dash", "skill_text_probes", "spec_name", "standard_error", "status_line",
           "training_summary", "waits", "weakest_keyframes", "write_report", "write_section", "zoo_index",
           "zoo_readme"]
