"""Entry point: ``python -m hnn_pl <command> ...``, or the console script ``hnn-pl``.

The top-level help is printed without importing Lightning, so it is instant.
"""

from __future__ import annotations

import sys
from pathlib import Path

USAGE = """usage: {prog} <command> [options]

Hamiltonian Neural Networks (Greydanus et al., 2019) with PyTorch Lightning.

commands:
  fit        train a model:        {prog} fit --config spring.yaml
  validate   validate a checkpoint: ... validate --config spring.yaml --ckpt_path PATH
  test       test a checkpoint (losses and rollout metrics)
  predict    predicted dy/dt on the held-out states
  reproduce  train and evaluate every task x model x seed, write RESULTS.md
             ({prog} reproduce --help)

A --config that is not a file is looked up in the bundled configs (".yaml" optional).
Classes go by their short names: {prog} fit --model HNN --data SimulatedData
--data.system MassSpring; `--model.help HNN` lists a class's options.
`{prog} <command> --help` lists every option of a command; --version prints the version.

bundled configs: {configs}
"""


def program_name() -> str:
    """``hnn-pl`` when run as the console script, else ``python -m hnn_pl``."""
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return "hnn-pl" if name.startswith("hnn-pl") else "python -m hnn_pl"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        from hnn_pl.config_paths import bundled_configs

        configs = ", ".join(bundled_configs()) or "(none)"
        print(USAGE.format(prog=program_name(), configs=configs))
        return
    if argv[0] in ("-V", "--version"):
        from hnn_pl import __version__

        print(f"hnn_pl {__version__}")
        return
    if argv[0] == "reproduce":
        from hnn_pl.reproduce import main as reproduce

        sys.exit(reproduce(argv[1:]))
    from hnn_pl.cli import cli_main

    cli_main(argv)


if __name__ == "__main__":
    main()
