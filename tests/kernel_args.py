"""The sub-step kernel's groups for tests that call it directly, built by name as the engine builds them."""

from __future__ import annotations

from pan1_env.kernel_groups import (
    ArmModel,
    ArmState,
    Command,
    EndEffectorObstacles,
    StepOutputs,
    Stepped,
    Stepping,
    plain,
)


def kernel_groups(batch, damping, passive, q, v, momentum, v_prev, has_prev, rows, window, command, torque, filter_on,
                  centers, radii, mask, rcbf, ke, dt, n_sub, v_max, outputs) -> tuple:
    """group_advance's plain groups after its size tuples (``batch``: the arms' ``lam, lengths, base, phi``, an
    :class:`~pan1_env.dynamics.ArmBatch`); ``outputs`` in :class:`StepOutputs`' order."""
    return tuple(plain(group) for group in (
        ArmModel(lam=batch.lam, lengths=batch.lengths, base=batch.base, phi=batch.phi, damping=damping,
                 passive=passive),
        ArmState(q=q, v=v, momentum=momentum, v_prev=v_prev, has_prev=has_prev),
        Stepped(rows=rows, window=window), Command(command=command, torque_mode=torque, filter_on=filter_on),
        EndEffectorObstacles(centers=centers, radii=radii, mask=mask), rcbf,
        Stepping(ke=ke, dt=dt, n_sub=n_sub, v_max=v_max), StepOutputs(*outputs)))
