"""Helpers shared by the simulator tests (imported as a plain module: pytest puts tests/ on sys.path)."""

from __future__ import annotations

import pytest


def require_simulator(*modules: str, libero: bool = False) -> None:
    """Skip the calling test module (at import) without MuJoCo, mink, ``modules``, the Panda model or, with
    ``libero``, the LIBERO asset wheels; CI installs them all."""
    for name in ("mujoco", "mink", *modules):
        pytest.importorskip(name)
    from abm.sim.assets import AssetNotFoundError, libero_available, panda_dir

    try:
        panda_dir()
    except AssetNotFoundError as err:  # pragma: no cover - CI installs the package
        pytest.skip(str(err), allow_module_level=True)
    if libero and not libero_available():  # pragma: no cover - CI installs the asset wheels
        pytest.skip("LIBERO asset wheels not installed", allow_module_level=True)


def teleport(sim, index: int, xyz) -> None:
    """Put free object ``index`` at ``xyz`` (world metres), upright and at rest, and update the kinematics."""
    import mujoco

    adr = sim.model.joint(f"obj{index}_free").qposadr[0]
    sim.data.qpos[adr:adr + 3] = xyz
    sim.data.qpos[adr + 3:adr + 7] = [1, 0, 0, 0]
    sim.data.qvel[:] = 0
    mujoco.mj_forward(sim.model, sim.data)
