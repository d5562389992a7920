"""``hnn-pl reproduce``: the command line of :mod:`hnn_pl.experiments.reproduce` (which
declares the options), its runs built by :func:`hnn_pl.commands.cli.quiet_run`."""

from __future__ import annotations


def main(argv: list[str] | None = None) -> int:
    from hnn_pl.commands.cli_errors import OneLineParser, program_name
    from hnn_pl.experiments import reproduce

    description = reproduce.__doc__.split("\n\n")[0]
    parser = OneLineParser(prog=f"{program_name()} reproduce", description=description)
    call = reproduce.parse(parser, argv)
    from hnn_pl.commands.cli import quiet_run  # after parsing: --help without Lightning

    return reproduce.run(call, quiet_run)
