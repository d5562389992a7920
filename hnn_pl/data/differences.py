"""Finite-difference derivatives of observed trajectories: what the trajectory objective
is compared against (a user with a recording and a derivative-only model would do this)."""

from __future__ import annotations

import torch
from torch import Tensor


def central_differences(y: Tensor, t: Tensor, traj: Tensor) -> Tensor:
    """``dy/dt`` estimated at every observed sample of a flat table.

    Interior samples: ``(y_{i+1} − y_{i−1}) / (t_{i+1} − t_{i−1})``; a trajectory's
    first and last samples: the one-sided difference with their neighbour. Uneven
    spacing is honoured (the real time gaps).

    Args:
        y: ``(S, D)`` observed states, each trajectory's samples contiguous, in time order.
        t: ``(S,)`` their times.
        traj: ``(S,)`` trajectory ids; every trajectory has at least two samples.

    Returns:
        ``(S, D)``.
    """
    joined = (traj[:-1] == traj[1:]).nonzero().flatten()  # i and i + 1 share a trajectory
    lo, hi = torch.arange(len(traj)), torch.arange(len(traj))
    lo[joined + 1] = joined
    hi[joined] = joined + 1
    return (y[hi] - y[lo]) / (t[hi] - t[lo])[:, None]


def smoothed_velocity(q: Tensor, t: Tensor, traj: Tensor, half: int = 2) -> Tensor:
    """``dq/dt`` at every observed sample from a local quadratic least-squares fit.

    Sample ``i`` of a trajectory of ``n`` samples is fitted with ``q(s) ≈ a + b s + c s²``,
    ``s = t − t_i``, over the ``m = min(n, 2·half + 1)`` consecutive samples of its own
    trajectory centred on it (shifted inwards at the ends), and ``b`` is returned:
    a Savitzky–Golay derivative with the real, possibly uneven, times. Its noise is
    ``~σ/(Δt·m^{3/2})`` against central differences' ``σ/(√2 Δt)``.

    Args:
        q: ``(S, k)`` observed positions, each trajectory's samples contiguous, in time order.
        t: ``(S,)`` their times.
        traj: ``(S,)`` trajectory ids; every trajectory has at least two samples.

    Returns:
        ``(S, k)``.
    """
    S = len(traj)
    first = torch.ones(S, dtype=torch.bool)
    first[1:] = traj[1:] != traj[:-1]
    start = torch.cummax(torch.where(first, torch.arange(S), 0), 0).values
    counts = torch.bincount(torch.cumsum(first.long(), 0) - 1)
    n = counts[torch.cumsum(first.long(), 0) - 1]
    m = torch.clamp(n, max=2 * half + 1)
    lo = torch.minimum(torch.clamp(torch.arange(S) - half, min=0), start + n - m)
    lo = torch.maximum(lo, start)
    offsets = torch.arange(2 * half + 1)
    idx = lo[:, None] + torch.minimum(offsets, m[:, None] - 1)
    used = offsets < m[:, None]
    s = (t[idx] - t[:, None]) * used
    span = s.abs().amax(1, keepdim=True).clamp_min(torch.finfo(s.dtype).tiny)
    u = s / span
    degree = torch.where(m >= 3, 2, 1)
    basis = torch.stack([torch.ones_like(u), u, u**2 * (degree[:, None] == 2)], -1)
    basis = basis * used[..., None]
    coef = torch.linalg.pinv(basis) @ (q[idx] * used[..., None])
    return coef[:, 1] / span


def position_pairs(q: Tensor, t: Tensor, traj: Tensor) -> tuple[Tensor, Tensor]:
    """Derivative pairs from positions alone, the way a user with a derivative-only model
    would make them: ``x = (q, v)``, ``dx/dt = (v, a)`` with ``v`` the
    :func:`central_differences` of ``q`` and ``a`` those of ``v`` (unit mass: the
    momentum read as the velocity). ``q (S, k)``, ``t (S,)``, ``traj (S,)`` as there;
    returns ``x, dx`` each ``(S, 2k)``."""
    v = central_differences(q, t, traj)
    a = central_differences(v, t, traj)
    return torch.cat([q, v], -1), torch.cat([v, a], -1)
