"""Threads under load: the whole ``hnn-pl fit`` process of a fast config on an idle
machine and beside a competing busy process, with 1 and 2 torch threads, with
``OMP_WAIT_POLICY=PASSIVE`` and with ``--threads auto`` (the default)."""

from __future__ import annotations

import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

from common import main, table

TITLE = "Threads under load"
SETTINGS = {
    "1 thread": (["--threads=1"], {}),
    "2 threads": (["--threads=2"], {}),
    "2 threads, OMP_WAIT_POLICY=PASSIVE": (["--threads=2"], {"OMP_WAIT_POLICY": "PASSIVE"}),
    "auto (default)": ([], {}),
}
BUSY = "import itertools\nfor _ in itertools.count(): pass"


def fit_process(config: str, args: list[str], env: dict, steps: int | None = None) -> float:
    """Seconds of one ``python -m hnn_pl fit`` process in a fresh directory."""
    extra = [f"--trainer.max_steps={steps}"] if steps else []
    with tempfile.TemporaryDirectory() as cwd:
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "hnn_pl", "fit", f"--config={config}", *args, *extra],
            cwd=cwd,
            env={**os.environ, "PYTHONWARNINGS": "ignore", **env},
            check=True,
            capture_output=True,
        )
        return time.perf_counter() - t0


def times(config: str, args, env, repeats: int, busy: bool, steps=None) -> float:
    competitor = subprocess.Popen([sys.executable, "-c", BUSY]) if busy else None
    try:
        time.sleep(1.0 if busy else 0.0)
        return statistics.median(fit_process(config, args, env, steps) for _ in range(repeats))
    finally:
        if competitor:
            competitor.kill()
            competitor.wait()


def run(quick: bool = False, config: str = "spring_fast.yaml") -> str:
    repeats, steps = (1, 5) if quick else (3, None)
    rows = []
    for name, (args, env) in SETTINGS.items():
        if quick and name != "1 thread":
            continue
        idle = times(config, args, env, repeats, busy=False, steps=steps)
        busy = math.nan if quick else times(config, args, env, repeats, busy=True, steps=steps)
        rows.append([name, f"{idle:.1f}", f"{busy:.1f}", f"{busy / idle:.2f}"])
        print(rows[-1], flush=True)
    paper = math.nan if quick else times("spring.yaml", ["--threads=1"], {}, 2, False)
    caption = (
        f"`python -m hnn_pl fit --config {config}` as a user runs it (start-up, data, training, "
        "final rollout and figures, TensorBoard logs and checkpoint in a fresh directory), "
        f"median of {repeats} processes; *busy*: beside one process spinning a Python loop "
        f"(one core's worth of load), started 1 s before. For scale: `spring.yaml` (paper "
        f"recipe), whole process, idle, 1 thread: {paper:.1f} s."
    )
    header = "torch threads | idle s | busy s | busy / idle"
    return caption + "\n\n" + table(header, rows)


if __name__ == "__main__":
    main({"threads": sys.modules[__name__]}, None)
