"""The experiments: the layer that reproduces the paper, above the library and beside
the command line.

:mod:`~hnn_pl.experiments.paper` (the paper's table as data: published numbers, configs,
costs, targets), ``reproduce`` in three steps (:mod:`~hnn_pl.experiments.collect`,
:mod:`~hnn_pl.experiments.summary`, :mod:`~hnn_pl.experiments.results`, driven by
:mod:`~hnn_pl.experiments.reproduce`; :mod:`~hnn_pl.experiments.positions` for
``--recipe positions``), :mod:`~hnn_pl.experiments.stress`, time to accuracy
(:mod:`~hnn_pl.experiments.tta`) and the report writers
(:mod:`~hnn_pl.experiments.report`). They import the library and never the commands
(``tests/test_imports.py``): a command hands in how a run is built from a config
(:class:`~hnn_pl.experiments.collect.Build`).
"""
