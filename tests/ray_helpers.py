"""The Ray tests' shared parts: one local Ray with 2 CPUs (:func:`local_ray`, each module's ``cluster`` fixture)
and the words of an ``abm data generate`` of pick_block (:func:`generate_words`)."""

from __future__ import annotations

import os

import pytest

ray = pytest.importorskip("ray")


def local_ray():
    """Start a local Ray with 2 CPUs, yield its address, shut it down."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, object_store_memory=150 * 1024**2)
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


def generate_words(out, backend, episodes=2, extra=()):
    """``abm data generate`` of ``episodes`` pick_block demonstrations (2 workers, 16 px) into ``out``."""
    return ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", str(episodes),
            "--workers", "2", "--resolution", "16", "--out", str(out), "--backend", backend, *extra]
