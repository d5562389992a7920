"""The bundled configs. This file makes ``configs/`` the package ``hnn_pl.configs``
(see ``package-dir`` in pyproject.toml), so the YAML files ship in the wheel and an
editable install finds them too; ``hnn_pl.commands.config_paths`` reads them."""
