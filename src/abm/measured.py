"""What the first hour costs, measured: one generated file that every stated time and expected result reads.

``abm/configs/measured.json`` is written by ``benchmarks/first_hour.py`` from measured runs (the quickstart on a
fresh clone, ``abm zoo eval`` with the default and with AVX-512-free kernels, ``abm --help``, the test script, the
speed benchmarks); nothing in it is typed by hand. ``abm quickstart --help``, ``abm zoo eval --help`` and its last
lines, the README's first-hour block and speed table and docs/evaluation.md's quickstart block are made from it, so
one re-measurement changes every place at once.

Sections of the file (each optional; a missing one reads "not measured"):

* ``quickstart``: ``wall_minutes``, ``cpu_minutes`` (user + system of every process), ``machine``, ``date``,
  ``commit``, ``grounder``, ``load`` (what else ran), ``results``: ``{method: {split: [successes, episodes]}}``;
* ``zoo_eval``: ``wall_minutes``, ``machine``, ``date``, ``commit``, ``results`` as above (the compared models);
* ``cross_cpu``: the same ``abm zoo eval`` with AVX-512 switched off against the default kernels: ``episodes``,
  ``differing`` (success flipped), ``cells``, ``cells_differing``, ``max_per_cell``, ``identical_trajectories``,
  ``kernels``, ``machine``;
* ``help``: ``seconds`` (median wall time of ``abm --help``);
* ``tests``: ``pytest_minutes``, ``ci_minutes`` (``bash .ci/run`` on a fresh clone, setup included), ``machine``;
* ``speed``: the README's speed table (``benchmarks/first_hour.py --speed`` runs its commands): ``render_ms``,
  ``policy_small_s``, ``policy_paper_s``, ``paper_parameters``, ``mask_field_s``, ``train_samples_per_s``,
  ``generation_episodes_per_min`` (lowest and highest over the tasks), ``machine``, ``date``, ``commit``.
"""

from __future__ import annotations

import functools
import json
from importlib import resources
from typing import Any

#: the generated file, inside the package
FILE = "measured.json"


@functools.cache
def measured() -> dict[str, Any]:
    """The file's sections (module doc); ``{}`` when the package has no such file."""
    try:
        text = resources.files("abm").joinpath("configs", FILE).read_text()
    except FileNotFoundError:
        return {}
    data: dict[str, Any] = json.loads(text)
    return data


def _minutes(value: float) -> str:
    return f"{value:.0f} min" if value >= 10 else f"{value:.1f} min"


def _results(results: dict[str, dict[str, list[int]]]) -> str:
    return "; ".join(f"{method} " + ", ".join(f"{s}/{n} {split}" for split, (s, n) in splits.items())
                     for method, splits in results.items())


def quickstart_text() -> str:
    """``abm quickstart``'s measured time and results in one sentence."""
    q = measured().get("quickstart")
    if not q:
        return "its time and results are not measured yet"
    return (f"measured {_minutes(q['wall_minutes'])} wall ({_minutes(q['cpu_minutes'])} of CPU) on "
            f"{q['machine']}, {q['date']}, grounded with the {q['grounder']}: {_results(q['results'])} "
            "(episodes succeeded; a run on other CPUs differs by a few episodes)")


def zoo_eval_text(results: bool = True) -> str:
    """``abm zoo eval``'s measured time in a few words, and (``results``) what succeeded."""
    z = measured().get("zoo_eval")
    if not z:
        return "not measured yet"
    took = f"~{_minutes(z['wall_minutes'])} on {z['machine']}"
    return f"{took}, {_results(z['results'])} (episodes succeeded)" if results else took


def reproducibility_text() -> str:
    """What stays the same where: the same machine gives identical outcomes; across CPU types, how many episodes
    of ``abm zoo eval`` flipped when AVX-512 was switched off."""
    c = measured().get("cross_cpu")
    same = ("On one machine, the same code, seeds and models give identical outcomes, episode by episode (the "
            "trajectory digests match)")
    if not c:
        return same + "; across CPU types it is not measured yet."
    return (f"{same}. Across CPU types the floats of the network differ in their last bits and an episode near "
            f"its tolerance can flip: with {c['kernels']}, {c['differing']} of {c['episodes']} episodes of "
            f"`abm zoo eval` changed outcome ({c['cells_differing']} of {c['cells']} cells, at most "
            f"{c['max_per_cell']} episode(s) in one; measured on {c['machine']}).")


def help_text() -> str:
    """``abm --help``'s measured wall time."""
    h = measured().get("help")
    return f"{h['seconds']:.1f} s" if h else "not measured"


def tests_text() -> str:
    """The test script's measured time."""
    t = measured().get("tests")
    if not t:
        return "not measured yet"
    return (f"pytest {_minutes(t['pytest_minutes'])} on {t['machine']}, {_minutes(t['ci_minutes'])} for "
            "`.ci/run` with the setup on a fresh clone")
