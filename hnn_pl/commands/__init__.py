"""The commands, ``python -m hnn_pl {fit,validate,test,predict,reproduce,stress,bump}``:
argument parsing and dispatch (the work of ``reproduce`` and ``stress`` is in
:mod:`hnn_pl.experiments`). Nothing else in the package imports this one."""
