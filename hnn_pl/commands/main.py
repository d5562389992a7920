"""Entry point: ``python -m hnn_pl <command> ...``, or the console script ``hnn-pl``.

The top-level help imports no Lightning (instant). Bad input ends with one line,
``<prog>: error: <what>``, exit status 2 (``HNN_PL_TRACEBACK=1``: the traceback).
"""

from __future__ import annotations

import os
import sys

from hnn_pl.commands.cli_errors import USER_ERRORS, program_name, user_error

__all__ = ["USER_ERRORS", "main", "user_error"]

USAGE = """usage: {prog} <command> [options]

Hamiltonian Neural Networks (Greydanus et al., 2019) with PyTorch Lightning.

commands:
  fit        train a model:        {prog} fit --config spring.yaml
  validate   validate a checkpoint: ... validate --config spring.yaml --ckpt_path PATH
  test       test a checkpoint (losses and rollout metrics), logged into its run
  predict    roll a checkpoint out from the held-out (or your) starts: true and
             predicted states, energies, H_θ, metrics -> rollouts.pt in its run
  reproduce  train and evaluate every task x model x seed, write RESULTS.md
             ({prog} reproduce --help)
  stress     numerical stability of integrators and trained models, write
             STABILITY.md ({prog} stress --help)
  bump       change a trained HNN's learned energy and roll out ({prog} bump --help)

A --config that is not a file is looked up in the bundled configs (".yaml" optional);
--ckpt_path takes a checkpoint, a run (lightning_logs/spring_fast_hnn/version_0) or a
run name's directory (lightning_logs/spring_fast_hnn: its latest run).
Classes go by their short names: {prog} fit --model HNN --data SimulatedData
--data.system MassSpring; `--model.help HNN` lists a class's options.
`{prog} <command> --help` lists every option of a command; --version prints the version.

bundled configs: {configs}
"""


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        from hnn_pl.commands.config_paths import bundled_configs

        configs = ", ".join(bundled_configs()) or "(none)"
        print(USAGE.format(prog=program_name(), configs=configs))
        return
    if argv[0] in ("-V", "--version"):
        from hnn_pl import __version__

        print(f"hnn_pl {__version__}")
        return
    try:
        if argv[0] in ("reproduce", "bump", "stress"):  # light until they have parsed
            from hnn_pl.commands import bump, reproduce, stress

            plain = {"reproduce": reproduce, "bump": bump, "stress": stress}
            sys.exit(plain[argv[0]].main(argv[1:]))
        from hnn_pl.commands.cli import cli_main

        cli_main(argv)
    except Exception as err:
        message = user_error(err)
        if message is None or os.environ.get("HNN_PL_TRACEBACK"):
            raise
        print(f"{program_name()}: error: {message}", file=sys.stderr)
        sys.exit(2)
