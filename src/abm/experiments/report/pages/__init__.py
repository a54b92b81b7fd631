"""Generated pages and blocks outside an experiment spec's report: the quickstart's report folder
(:mod:`~abm.experiments.report.pages.quickstart`) and the grounding configurations' block of docs/grounding.md
(:mod:`~abm.experiments.report.pages.grounding_configs`). The measurements that feed them stay where they run (the
quickstart command, ``benchmarks/``); the text is written here. (A probe's tables are its spec's report sections:
``probe_fit``, ``probe_accuracy``, ``probe_rollouts``.)"""
