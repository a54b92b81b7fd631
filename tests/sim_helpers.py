"""Helpers shared by the simulator tests (imported as a plain module: pytest puts tests/ on sys.path)."""

from __future__ import annotations


def teleport(sim, index: int, xyz) -> None:
    """Put free object ``index`` at ``xyz`` (world metres), upright and at rest, and update the kinematics."""
    import mujoco

    adr = sim.model.joint(f"obj{index}_free").qposadr[0]
    sim.data.qpos[adr:adr + 3] = xyz
    sim.data.qpos[adr + 3:adr + 7] = [1, 0, 0, 0]
    sim.data.qvel[:] = 0
    mujoco.mj_forward(sim.model, sim.data)
