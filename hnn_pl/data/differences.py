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
