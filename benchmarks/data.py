"""``SimulatedData`` generation into an empty cache, and loading on a cache hit."""

from __future__ import annotations

import functools
import statistics
import sys
import tempfile
import time
from pathlib import Path

from common import main, measure, table

from hnn_pl.data import SimulatedData
from hnn_pl.systems import MassSpring, Pendulum, ThreeBody, TwoBody

TITLE = "Data generation"
NBODY = {"noise_std": 0.0, "test_fraction": 0.2, "test_first": True}
TASKS = (  # the bundled configs' parameters: system, trajectories, t_end, points per trajectory
    ("mass-spring", MassSpring, 50, 3, 30),
    ("pendulum", Pendulum, 50, 3, 45),
    ("two-body", TwoBody, 1000, 20, 50),
    ("three-body", ThreeBody, 5000, 5, 20),
)


def run(quick: bool) -> str:
    rows, repeats = [], 1 if quick else 3
    for name, system, k, t_end, points in TASKS[:2] if quick else TASKS:
        kwargs = dict(n_trajectories=k, t_span=(0, t_end), n_points=points)
        make = functools.partial(SimulatedData, system(), **kwargs, **(NBODY if k > 50 else {}))
        gen = []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory() as cache:
                t0 = time.perf_counter()
                make(cache_dir=cache).prepare_data()
                gen.append(time.perf_counter() - t0)
        with tempfile.TemporaryDirectory() as cache:
            (dm := make(cache_dir=cache)).setup()
            load, n = measure(lambda cache=cache, make=make: make(cache_dir=cache).setup(), 0.2)
            size = sum(p.stat().st_size for p in Path(cache).iterdir()) / 1e6
        n_rows = len(dm.x_train) + len(dm.x_test)
        gen = f"{statistics.median(gen):.3f}"
        rows.append([f"{name} ({k} × {points})", n_rows, gen, f"{1e3 * load:.2f}", f"{size:.2f}"])
    return (
        "`SimulatedData(...).prepare_data()` into an empty temporary cache (sampling, float64 "
        "ground truth: closed form for the spring, else dopri5 at rtol = atol = 1e-10; "
        f"split, `torch.save`), median of {repeats} run(s), 1 thread; cache hit: "
        "`SimulatedData(...).setup()` on the filled cache (`torch.load`, cast to float32), "
        "median of `blocked_autorange`.\n\n"
        + table("task | rows | generate (s) | cache hit (ms) | cache file (MB)", rows)
    )


if __name__ == "__main__":
    main({"data": sys.modules[__name__]}, None)
