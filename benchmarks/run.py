"""Run every benchmark and update BENCHMARKS.md between its section markers.

``python benchmarks/run.py [--quick] [--out PATH] [--only NAME ...]``; each topic also
runs alone: ``python benchmarks/integrators.py [--quick] [--out BENCHMARKS.md]``.
"""

import chain_fit
import data
import independent
import integrators
import lagrangian_step
import observer
import positions
import startup
import symplectic
import threads
import training
import trajectory
import tta
from common import REPORT, main

if __name__ == "__main__":
    topics = {
        "integrators": integrators,
        "training": training,
        "data": data,
        "startup": startup,
        "tta": tta,
        "threads": threads,
        "symplectic": symplectic,
        "independent": independent,
        "trajectory": trajectory,
        "observer": observer,
        "positions": positions,
        "lagrangian": lagrangian_step,
        "chain_fit": chain_fit,
    }
    main(topics, REPORT)
