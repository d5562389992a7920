"""Figures for TensorBoard (matplotlib, imported only when a picture is drawn).

The rollout figures have fixed margins: ``tight_layout`` measures every label by laying
the figure out once more, which took as long as drawing it (0.41 → 0.27 s a pair)."""

from __future__ import annotations

import torch
from torch import Tensor

from hnn_pl.evaluation import Rollout


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (the one matplotlib set-up)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def phase_portrait(r: Rollout, max_lines: int = 4):
    """True (solid) vs predicted (dashed) paths of the first ``max_lines`` rollouts.

    ``(q, p)`` for one degree of freedom; for more, the first half of the state is
    read as body positions ``(x₁, y₁, x₂, y₂, …)`` and each body's path is drawn.
    """
    plt = pyplot()
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
    fig.subplots_adjust(left=0.17, right=0.96, bottom=0.12, top=0.92)
    return fig


def _positions(path):
    q = path[:, : path.shape[-1] // 2]
    return [(q[:, 2 * i], q[:, 2 * i + 1]) for i in range(q.shape[-1] // 2)]


def energy_over_time(r: Rollout, max_lines: int = 4):
    """Physical energy along the true and predicted paths, and ``H_θ`` if present."""
    plt = pyplot()
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
    bottom = 0.14
    if r.has_frames:
        dt = float(r.t[1] - r.t[0]) if len(r.t) > 1 else float("nan")
        note = (
            f"The true paths are gym's semi-implicit Euler steps (dt = {dt:.3g}), which do not "
            "conserve the energy exactly: it oscillates along them."
        )
        fig.text(0.01, 0.01, note, fontsize=7, wrap=True)
        bottom = 0.22
    width = fig.get_figwidth()
    fig.subplots_adjust(
        left=0.85 / width, right=1 - 0.15 / width, bottom=bottom, top=0.85, wspace=0.4
    )
    return fig


def latent_portrait(r: Rollout, max_lines: int = 4):
    """The latent plane of a pixel rollout: encoded truth (solid), rollout (dashed)."""
    latent = Rollout(r.t, r.z_true, r.z_pred, r.e_true, r.e_pred)
    fig = phase_portrait(latent, max_lines)
    fig.axes[0].set(
        xlabel="z_q", ylabel="z_p", title="latent: encoded truth (solid), rollout (dashed)"
    )
    return fig


def figures(r: Rollout) -> dict:
    """``{tag: figure}`` of a rollout: ``rollout/phase_portrait`` (pixel models: the
    latent plane) and ``rollout/energy`` (when the data has an energy)."""
    portrait = latent_portrait(r) if r.has_frames else phase_portrait(r)
    if r.e_true is None:
        return {"rollout/phase_portrait": portrait}
    return {"rollout/phase_portrait": portrait, "rollout/energy": energy_over_time(r)}


def frames_figure(r: Rollout, trajectory: int = 0, n_strip: int = 10):
    """:func:`frames_image` with its rows (true, predicted) and times labelled."""
    plt = pyplot()
    image = frames_image(r, trajectory, n_strip)[0]
    height, width = image.shape
    n = min(n_strip, r.x_true.shape[0])
    idx = torch.linspace(0, r.x_true.shape[0] - 1, n).round().long()
    column = (width + 1) / n
    row = (height - 2) / 2
    fig, ax = plt.subplots(figsize=(width / 80 + 1.2, height / 80 + 1.0), dpi=80)
    ax.imshow(image.numpy(), cmap="gray", vmin=0, vmax=255)
    ax.set_xticks([column * (i + 0.5) - 0.5 for i in range(n)])
    ax.set_xticklabels([f"{float(r.t[k]):.2f}" for k in idx])
    ax.set_yticks([row / 2, row + 2 + row / 2])
    ax.set_yticklabels(["true", "predicted"])
    ax.set_xlabel("t")
    ax.set_title(f"held-out trajectory {trajectory}: true frames and decoded rollout")
    fig.tight_layout()
    return fig


def frames_image(r: Rollout, trajectory: int = 0, n_strip: int = 10) -> Tensor:
    """True (top) and decoded (bottom) frames of one pixel rollout: ``(1, H, W)`` uint8.

    ``n_strip`` frames evenly spaced over the rollout, the second frame of each
    pair, mapped from ``[0, max of the true frames]`` to ``[0, 255]``.
    """
    from hnn_pl.render import frame_strip

    n = r.x_true.shape[0]
    side = int(round((r.x_true.shape[-1] // 2) ** 0.5))
    idx = torch.linspace(0, n - 1, min(n_strip, n)).round().long()

    def second(x: Tensor) -> Tensor:
        return x[idx, trajectory, side * side :].reshape(-1, side, side).float().cpu()

    true, pred = second(r.x_true), second(r.x_pred)
    vmax = float(true.max()) or 1.0
    top, bottom = frame_strip(true, vmax=vmax), frame_strip(pred, vmax=vmax)
    gap = torch.full((2, top.shape[1]), 128, dtype=torch.uint8)
    return torch.cat([top, gap, bottom])[None]


def bump_figure(before: Rollout, after: Rollout, delta: float, path) -> None:
    """``path`` (a PNG): the rollouts ``before`` and ``after`` an energy bump by ``delta``
    (:func:`hnn_pl.bump.energy_bump`): decoded frames for a pixel model, else the phase
    portrait and ``H_θ`` over time."""
    plt = pyplot()
    if before.x_pred is not None:
        n = min(8, before.x_pred.shape[0])
        idx = torch.linspace(0, before.x_pred.shape[0] - 1, n).long()
        side = int(round((before.x_pred.shape[-1] // 2) ** 0.5))
        fig, axes = plt.subplots(2, n, figsize=(1.4 * n, 3.2))
        for row, (traj, label) in enumerate(((before, "original"), (after, f"ΔH_θ = {delta:.3g}"))):
            for col, k in enumerate(idx.tolist()):
                frame = traj.x_pred[k, 0, : side * side].reshape(side, side).float()
                axes[row, col].imshow(frame.detach().numpy(), cmap="gray")
                axes[row, col].axis("off")
            axes[row, 0].set_title(label, fontsize=8, loc="left")
    else:
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.4))
        for traj, style in ((before, "-"), (after, "--")):
            k = traj.y_pred.shape[-1] // 2
            for b in range(traj.y_pred.shape[1]):
                ax1.plot(traj.y_pred[:, b, 0], traj.y_pred[:, b, k], style, color=f"C{b % 10}")
                ax2.plot(traj.t, traj.h_pred[:, b], style, color=f"C{b % 10}")
        ax1.set(xlabel="q", ylabel="p", title="learned dynamics before and after the bump")
        ax2.set(xlabel="t", ylabel="H_θ", title="H_θ: moved by ΔH, then kept")
        styles = [
            plt.Line2D([], [], color="k", ls="-", label="original (one colour per start)"),
            plt.Line2D([], [], color="k", ls="--", label=f"bumped by ΔH_θ = {delta:.3g}"),
        ]
        fig.legend(handles=styles, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0 if before.x_pred is not None else 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
