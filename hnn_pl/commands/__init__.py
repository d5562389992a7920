"""The commands: ``python -m hnn_pl {fit,validate,test,predict,reproduce,stress,bump}``.

The command line (:mod:`~hnn_pl.commands.main`, the LightningCLI in
:mod:`~hnn_pl.commands.cli`), the report writers (``reproduce``, ``stress``, ``bump``,
:mod:`~hnn_pl.commands.report`) and the figures they draw. The library (``integrate``,
``systems``, ``nets``, ``data``, ``models``, ``evaluation``, ``callbacks``) never imports
this package (``tests/test_imports.py``).
"""
