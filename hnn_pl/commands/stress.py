"""``hnn-pl stress``: the command line of :mod:`hnn_pl.experiments.stress` (which
declares the options), its trained models built by :func:`hnn_pl.commands.cli.quiet_run`."""

from __future__ import annotations


def main(argv: list[str] | None = None) -> int:
    from hnn_pl.commands.cli_errors import OneLineParser, program_name
    from hnn_pl.experiments import stress

    description = stress.__doc__.split("\n\n")[0]
    parser = OneLineParser(prog=f"{program_name()} stress", description=description)
    args = stress.parse(parser, argv)
    from hnn_pl.commands.cli import quiet_run  # after parsing: --help without Lightning

    return stress.main(args, quiet_run)
