"""Generated pages and blocks outside an experiment spec's report: the quickstart's report folder
(:mod:`~abm.experiments.report.pages.quickstart`), the grounding configurations' block of docs/grounding.md
(:mod:`~abm.experiments.report.pages.grounding_configs`) and the zoom probe's tables
(:mod:`~abm.experiments.report.pages.zoom_probe`). The measurements that feed them stay where they run (the
quickstart command, ``benchmarks/``); the text is written here."""
