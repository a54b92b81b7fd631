"""Experiments as data: specs (``configs/experiments/NAME.yaml``), the engine that runs their stages, and the
report module that writes every generated block (README, docs/results, the model zoo's index).

* :mod:`abm.experiments.spec`: :class:`~abm.experiments.spec.ExperimentSpec` and its validating YAML loader;
* :mod:`abm.experiments.state`: where the files live, the committed outcomes and the carry of unfinished work;
* :mod:`abm.experiments.scheduler`: N commands at a time x T threads, local subprocesses or Ray;
* :mod:`abm.experiments.stages`: the engine (data -> ground -> train -> export -> eval -> diagnose -> report);
* :mod:`abm.experiments.report`: the tables, figures, setup and machine lines of every generated block.

The command line is ``abm experiment run|status|list`` (:mod:`abm.cli.experiment`).
"""
