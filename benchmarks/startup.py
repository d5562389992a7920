"""Wall time of fresh Python processes: the CLI's help and the package's imports."""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

from common import main, table

TITLE = "Start-up"
COMMANDS = (
    ("`python -c pass` (interpreter alone)", "pass"),
    ("`python -m hnn_pl --help`", None),
    ("`import hnn_pl; from hnn_pl import odeint`", "import hnn_pl; from hnn_pl import odeint"),
    ("`from hnn_pl import HNN` (Lightning)", "from hnn_pl import HNN"),
)


def run(quick: bool) -> str:
    rows, repeats = [], 1 if quick else 3
    for name, code in COMMANDS[:2] if quick else COMMANDS:
        cmd = (
            [sys.executable, "-m", "hnn_pl", "--help"]
            if code is None
            else [sys.executable, "-c", code]
        )
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t0)
        rows.append([name, f"{statistics.median(times):.2f}", repeats])
    return (
        "Wall time of a fresh process (`subprocess.run`, `time.perf_counter`), median of the "
        "runs (the first one warms the file cache).\n\n" + table("command | time (s) | runs", rows)
    )


if __name__ == "__main__":
    main({"startup": sys.modules[__name__]}, None)
