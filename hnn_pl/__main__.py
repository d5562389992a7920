"""``python -m hnn_pl <command>``: :func:`hnn_pl.commands.main.main`."""

from hnn_pl.commands.main import main

if __name__ == "__main__":
    main()
