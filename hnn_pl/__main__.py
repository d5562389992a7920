"""Entry point: ``python -m hnn_pl <command> ...``.

The top-level help is printed without importing Lightning, so it is instant.
"""

from __future__ import annotations

import sys

USAGE = """usage: python -m hnn_pl <command> [options]

Hamiltonian Neural Networks (Greydanus et al., 2019) with PyTorch Lightning.

commands:
  fit        train a model:        python -m hnn_pl fit --config spring.yaml
  validate   validate a checkpoint: ... validate --config spring.yaml --ckpt_path PATH
  test       test a checkpoint (losses and rollout metrics)
  predict    predicted dy/dt on the held-out states
  reproduce  train and evaluate every task x model x seed, write RESULTS.md
             (python -m hnn_pl reproduce --help)

A --config that is not a file is looked up in the bundled configs/ (".yaml" optional).
`python -m hnn_pl <command> --help` lists every option of a command.

bundled configs: {configs}
"""


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        from hnn_pl.config_paths import bundled_configs

        print(USAGE.format(configs=", ".join(bundled_configs()) or "(none)"))
        return
    if argv[0] == "reproduce":
        from hnn_pl.reproduce import main as reproduce

        sys.exit(reproduce(argv[1:]))
    from hnn_pl.cli import cli_main

    cli_main(argv)


if __name__ == "__main__":
    main()
