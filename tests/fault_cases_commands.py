"""Command faults for the CLI fault table (``test_faults.CASES``): every numeric option
of every command refused at parse time in one line naming it, and runs refused after
parsing (a data check at setup, the first batch) leaving nothing behind.

``CASES``: id → (argv, files, what the line must say); ``FILES``: files → the maker of
the case's working directory. Cases that prepare simulated data keep its cache in
``../cache``, beside the working directory: the cache is a complete, valid file shared
by runs, not the refused run's; the run directory, config, hparams and event files are.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch

FIT = ["fit", "--config", "spring_fast.yaml", "--trainer.max_steps=2"]
SHARED_CACHE = "--data.init_args.cache_dir=../cache"
BUMP = ["bump", "--config", "spring_fast.yaml", "--ckpt_path", "model.ckpt"]
REPRODUCE = ["reproduce", "--tasks", "spring", "--models", "hnn"]
RUN = Path("lightning_logs/spring_fast_hnn/version_0")


def _hnn_checkpoint(path: Path) -> None:
    """A Lightning checkpoint of a fresh HNN of 2-D states at ``path``."""
    import lightning

    from hnn_pl.models import HNN

    path.parent.mkdir(parents=True, exist_ok=True)
    hparams = {"_class_path": "hnn_pl.models.HNN", "input_dim": 2, "hidden_dim": 200}
    ckpt = {"state_dict": HNN().state_dict(), "hyper_parameters": hparams}
    ckpt |= {"hnn_pl_model_class": "hnn_pl.models.hnn.HNN"}
    torch.save(ckpt | {"pytorch-lightning_version": lightning.__version__}, path)


def _run(tmp: Path) -> None:
    """A finished ``spring_fast`` run: its checkpoint, config and hparams."""
    _hnn_checkpoint(tmp / RUN / "checkpoints" / "last.ckpt")
    (tmp / RUN / "config.yaml").write_text("seed_everything: 0\n")
    (tmp / RUN / "hparams.yaml").write_text("hidden_dim: 200\n")


def _bump_far_cache(tmp: Path) -> None:
    """``model.ckpt`` and ``far.yaml``: spring_fast with its data cache in ``../cache``."""
    _hnn_checkpoint(tmp / "model.ckpt")
    (tmp / "far.yaml").write_text(
        "base: spring_fast.yaml\ndata:\n  init_args: {cache_dir: ../cache}\n"
    )


FILES: dict[str, Callable[[Path], None]] = {
    "out-file": lambda tmp: (tmp / "notes.txt").write_text("mine\n"),
    "bump-far-cache": _bump_far_cache,
    "finished-run": _run,
}

INTEGER = "must be an integer >= {}, got '{}'"
FINITE = "must be a finite number, got '{}'"
POSITIVE = "must be a finite number > 0, got '{}'"

#: id: (argv, files, what the line must say)
CASES = {
    "bump-starts-zero": ([*BUMP, "--starts", "0"], "", "--starts " + INTEGER.format(1, 0)),
    "bump-starts-negative": ([*BUMP, "--starts", "-1"], "", "--starts " + INTEGER.format(1, -1)),
    "bump-starts-underscore": (
        [*BUMP, "--starts", "1_5"],
        "",
        "--starts " + INTEGER.format(1, "1_5"),
    ),
    "bump-n-points-zero": ([*BUMP, "--n_points", "0"], "", "--n_points " + INTEGER.format(2, 0)),
    "bump-n-points-one": ([*BUMP, "--n_points", "1"], "", "--n_points " + INTEGER.format(2, 1)),
    "bump-t-end-negative": ([*BUMP, "--t_end", "-1"], "", "--t_end " + POSITIVE.format(-1)),
    "bump-t-end-zero": ([*BUMP, "--t_end", "0"], "", "--t_end " + POSITIVE.format(0)),
    "bump-t-end-inf": ([*BUMP, "--t_end", "inf"], "", "--t_end " + POSITIVE.format("inf")),
    "bump-delta-nan": ([*BUMP, "--delta", "nan"], "", "--delta " + FINITE.format("nan")),
    "bump-delta-inf": ([*BUMP, "--delta", "inf"], "", "--delta " + FINITE.format("inf")),
    "bump-delta-overflow": ([*BUMP, "--delta", "1e999"], "", "--delta " + FINITE.format("1e999")),
    "bump-out-is-a-file": (
        [*BUMP, "--out", "notes.txt"],
        "out-file",
        "--out: notes.txt is a file; name a directory to write into",
    ),
    "bump-out-below-a-file": (
        [*BUMP, "--out", "notes.txt/bumps"],
        "out-file",
        "--out: notes.txt/bumps: notes.txt is not a directory",
    ),
    "bump-starts-beyond-the-data": (
        ["bump", "--config", "far.yaml", "--ckpt_path", "model.ckpt", "--starts", "1000"],
        "bump-far-cache",
        "--starts 1000: the data holds 25 held-out starts",
    ),
    "reproduce-seeds-zero": ([*REPRODUCE, "--seeds", "0"], "", "--seeds " + INTEGER.format(1, 0)),
    "reproduce-seeds-fraction": (
        [*REPRODUCE, "--seeds", "2.0"],
        "",
        "--seeds " + INTEGER.format(1, "2.0"),
    ),
    "reproduce-first-seed-negative": (
        [*REPRODUCE, "--first-seed", "-1"],
        "",
        "--first-seed " + INTEGER.format(0, -1),
    ),
    "reproduce-workers-negative": (
        [*REPRODUCE, "--workers", "-1"],
        "",
        "--workers " + INTEGER.format(0, -1),
    ),
    "reproduce-max-steps-zero": (
        [*REPRODUCE, "--max-steps", "0"],
        "",
        "--max-steps " + INTEGER.format(1, 0),
    ),
    "threads-zero": ([*FIT, "--threads", "0"], "", "--threads must be >= 1 or 'auto', got 0"),
    "threads-fraction": (
        [*FIT, "--threads", "1.5"],
        "",
        "--threads must be >= 1 or 'auto', got '1.5'",
    ),
    "seed-beyond-numpy": (
        [*FIT, "--seed_everything=-1"],
        "",
        "seed_everything must be true, false or an integer in [0, 4294967295], got -1",
    ),
    "trainer-check-val-zero": (
        [*FIT, "--trainer.check_val_every_n_epoch=0"],
        "",
        "trainer.check_val_every_n_epoch must be an integer >= 1, got 0",
    ),
    "trainer-val-check-interval-zero": (
        [*FIT, "--trainer.val_check_interval=0"],
        "",
        "trainer.val_check_interval must be a number > 0, got 0",
    ),
    "trainer-accumulate-zero": (
        [*FIT, "--trainer.accumulate_grad_batches=0"],
        "",
        "trainer.accumulate_grad_batches must be an integer >= 1, got 0",
    ),
    "trainer-sanity-steps-negative": (
        [*FIT, "--trainer.num_sanity_val_steps=-2"],
        "",
        "trainer.num_sanity_val_steps must be an integer >= -1, got -2",
    ),
    "window-longer-than-every-trajectory": (
        [
            "fit",
            "--config",
            "spring_traj.yaml",
            "--data.init_args.window=1000",
            "--trainer.max_steps=2",
            SHARED_CACHE,
        ],
        "",
        "window 1000 is longer than every train trajectory (at most 30 samples)",
    ),
    "objective-data-mismatch": (
        [*FIT, "--model.init_args.objective=trajectory", SHARED_CACHE],
        "",
        "model.init_args.objective: trajectory needs windows of observed samples",
    ),
    "test-refused-at-its-first-batch": (
        [
            "test",
            "--config",
            "spring_fast.yaml",
            "--ckpt_path",
            "lightning_logs/spring_fast_hnn",
            "--data.init_args.window=5",
            "--model.init_args.objective=derivative",
            SHARED_CACHE,
        ],
        "finished-run",
        "serves windows, which only the trajectory objective uses",
    ),
}
