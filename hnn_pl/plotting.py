"""Figures for TensorBoard (matplotlib, imported only when a picture is drawn)."""

from __future__ import annotations

from hnn_pl.rollout import Rollout


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def phase_portrait(r: Rollout, max_lines: int = 4):
    """True (solid) vs predicted (dashed) paths of the first ``max_lines`` rollouts.

    ``(q, p)`` for one degree of freedom; for more, the first half of the state is
    read as body positions ``(x₁, y₁, x₂, y₂, …)`` and each body's path is drawn.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(4.5, 4.5), dpi=80)
    d = r.y_true.shape[-1]
    for b in range(min(max_lines, r.y_true.shape[1])):
        for y, style in ((r.y_true, "-"), (r.y_pred, "--")):
            path = y[:, b].double().cpu()
            pairs = [(path[:, 0], path[:, 1])] if d == 2 else _positions(path)
            for i, (u, v) in enumerate(pairs):
                ax.plot(u, v, style, color=f"C{(b * len(pairs) + i) % 10}", lw=1.2)
    ax.set_xlabel("q" if d == 2 else "x")
    ax.set_ylabel("p" if d == 2 else "y")
    ax.set_title("true (solid) vs predicted (dashed)")
    ax.set_aspect("equal", adjustable="datalim")
    fig.tight_layout()
    return fig


def _positions(path):
    q = path[:, : path.shape[-1] // 2]
    return [(q[:, 2 * i], q[:, 2 * i + 1]) for i in range(q.shape[-1] // 2)]


def energy_over_time(r: Rollout, max_lines: int = 4):
    """Physical energy along the true and predicted paths, and ``H_θ`` if present."""
    plt = _pyplot()
    ncols = 1 if r.h_pred is None else 2
    fig, axes = plt.subplots(1, ncols, figsize=(4.5 * ncols, 3.5), dpi=80, squeeze=False)
    t = r.t.double().cpu()
    for b in range(min(max_lines, r.e_true.shape[1])):
        axes[0, 0].plot(t, r.e_true[:, b].double().cpu(), "-", color=f"C{b}", lw=1.2)
        axes[0, 0].plot(t, r.e_pred[:, b].double().cpu(), "--", color=f"C{b}", lw=1.2)
        if r.h_pred is not None:
            axes[0, 1].plot(t, r.h_pred[:, b].double().cpu(), color=f"C{b}", lw=1.2)
    axes[0, 0].set(xlabel="t", ylabel="energy", title="energy: true (solid), predicted (dashed)")
    if r.h_pred is not None:
        axes[0, 1].set(xlabel="t", ylabel="H_θ", title="learned H_θ along the rollout")
    fig.tight_layout()
    return fig
