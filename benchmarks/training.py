"""Cost of one training step: HNN (closed-form and autograd ∇H) and baseline, 1 and 2
threads; the same step inside Lightning's ``Trainer.fit``; ``torch.compile``."""

from __future__ import annotations

import itertools
import os
import statistics
import sys
import tempfile
import time
import warnings
from unittest import mock

import torch
from common import main, measure, ms, table

from hnn_pl.commands.cli import QUIET_TRAINER
from hnn_pl.nets import MLP, DirectField, HamiltonianField

TITLE = "Training step"
SHAPES = ((750, 2, "spring, full batch"), (445, 2, "real pendulum, full batch"))
SHAPES += ((200, 8, "two-body batch"), (600, 12, "three-body batch"))
KINDS = ("HNN closed-form", "HNN autograd", "baseline")


def make_field(kind: str, d: int) -> torch.nn.Module:
    torch.manual_seed(0)
    if kind == "baseline":
        return DirectField(MLP(d, d))
    return HamiltonianField(MLP(d, 1), closed_form=kind == "HNN closed-form")


def make_step(field, x, dx, loss=None):
    """``zero_grad``, MSE(field(x), dx), ``backward``, Adam step."""
    loss = loss or (lambda: torch.nn.functional.mse_loss(field.vector_field(None, x), dx))
    opt = torch.optim.Adam(field.parameters(), lr=1e-3)

    def step():
        opt.zero_grad(set_to_none=True)
        loss().backward()
        opt.step()

    return step


def data(n: int, d: int):
    g = torch.Generator().manual_seed(0)
    return torch.randn(n, d, generator=g), torch.randn(n, d, generator=g)


def steps_table(quick: bool) -> str:
    rows, mrt = [], 0.1 if quick else 0.3
    for n, d, what in SHAPES[:1] if quick else SHAPES:
        x, dx = data(n, d)
        for th in (1,) if quick else (1, 2):
            t = [measure(make_step(make_field(k, d), x, dx), mrt, th)[0] for k in KINDS]
            ratios = [f"{t[1] / t[0]:.2f}", f"{t[0] / t[2]:.2f}"]
            rows.append([f"{n}×{d} ({what})", th, *map(ms, t), *ratios])
    return (
        "One step = `zero_grad`, MSE(field(x), dx), `backward`, Adam; float32 random data, "
        "`MLP(d → 200 → 200 → out)`; closed-form: `MLP.value_and_input_grad`, autograd: "
        "`closed_form=False` (double backward). Median of `blocked_autorange` "
        f"(min_run_time {mrt} s).\n\n"
        + table(
            f"batch × dim | threads | {' (ms) | '.join(KINDS)} (ms) | autograd / closed-form | "
            "closed-form / baseline",
            rows,
        )
    )


def lightning_table(quick: bool) -> str:
    import lightning as L

    from hnn_pl.commands.cli import quiet_lightning
    from hnn_pl.data import TensorBatches
    from hnn_pl.models import HNN

    quiet_lightning()
    n_fit, rows = 30 if quick else 150, []

    class Clock(L.Callback):
        def __init__(self):
            self.stamps = []

        def on_train_batch_end(self, *args, **kwargs):
            self.stamps.append(time.perf_counter())

    for (n, d, what), inner in itertools.product(SHAPES[:1] if quick else SHAPES, (1, 10)):
        x, dx = data(n, d)
        torch.manual_seed(0)
        model = HNN(input_dim=d, inner_steps=inner)
        step = make_step(make_field(KINDS[0], d), x, dx)
        before = measure(step, 0.1 if quick else 0.3)[0]
        clock = Clock()
        trainer = L.Trainer(
            max_steps=n_fit, accelerator="cpu", devices=1, num_sanity_val_steps=0,
            **{**QUIET_TRAINER, "callbacks": [clock]},
        )  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            batches = TensorBatches((x, dx), None, repeats=n_fit // inner)
            trainer.fit(model, train_dataloaders=batches)
            total = time.perf_counter() - t0
        plain = (before + measure(step, 0.1 if quick else 0.3)[0]) / 2
        skip = max(1, 5 // inner)
        per = statistics.median(
            b - a for a, b in zip(clock.stamps[skip:], clock.stamps[skip + 1 :])
        )
        per /= inner
        fixed = total - (clock.stamps[-1] - clock.stamps[0])
        over = [f"{(per - plain) * 1e3:.2f}", f"{100 * (per - plain) / plain:.0f}", f"{fixed:.2f}"]
        rows.append([f"{n}×{d} ({what})", inner, ms(plain), ms(per), *over])
    return (
        f"`hnn_pl.models.HNN` in `Trainer.fit(max_steps={n_fit})` (logger, checkpointing, "
        "progress bar, validation off; full batch from `TensorBatches`), 1 thread: median "
        "interval between `on_train_batch_end` calls after step 5, divided by the optimiser "
        "steps per batch (`inner_steps`: 1, or 10 as the fast recipes); plain loop: the HNN "
        "closed-form step, mean of the `blocked_autorange` medians just before and after "
        "the fit. Fixed cost: `fit` wall time minus the first-to-last step span (set-up, "
        "first step, teardown).\n\n"
        + table(
            "batch × dim | inner_steps | plain loop (ms) | in Trainer.fit (ms) | "
            "overhead (ms/step) | overhead (%) | fit fixed cost (s)",
            rows,
        )
    )


def compile_table() -> str:
    x, dx = data(750, 2)
    eager = measure(make_step(make_field(KINDS[0], 2), x, dx), 0.5)[0]
    field = make_field(KINDS[0], 2)
    loss = torch.compile(lambda: torch.nn.functional.mse_loss(field.vector_field(None, x), dx))
    step = make_step(field, x, dx, loss)
    with (
        tempfile.TemporaryDirectory() as cache,
        mock.patch.dict(os.environ, TORCHINDUCTOR_CACHE_DIR=cache),
    ):
        try:
            t0 = time.perf_counter()
            step()  # compile with an empty inductor cache
            first = time.perf_counter() - t0
            compiled = measure(step, 0.5)[0]
            row = [f"{first:.1f}", ms(eager), ms(compiled), f"{eager / compiled:.2f}"]
        except Exception as err:  # report whatever compile raises
            row = [f"failed: {type(err).__name__}", ms(eager), "", ""]
    return (
        "`torch.compile` (inductor) of the closed-form HNN loss at 750×2, 1 thread, the "
        "step as above (backward compiled too); first step with an empty inductor cache.\n\n"
        + table("first step (s) | eager (ms) | compiled (ms) | speed-up", [row])
    )


def run(quick: bool) -> str:
    parts = [steps_table(quick), "### Through Lightning", lightning_table(quick)]
    if not quick:
        parts += ["### torch.compile", compile_table()]
    return "\n\n".join(parts)


if __name__ == "__main__":
    main({"training": sys.modules[__name__]}, None)
