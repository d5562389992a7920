"""The commands: ``python -m hnn_pl {fit,validate,test,predict,reproduce,stress,bump}``.

Argument parsing and dispatch: the command line (:mod:`~hnn_pl.commands.main`, the
LightningCLI in :mod:`~hnn_pl.commands.cli`), ``bump``, and the command lines of
``reproduce`` and ``stress`` (their work is in :mod:`hnn_pl.experiments`). Neither the
library nor the experiments import this package (``tests/test_imports.py``).
"""
