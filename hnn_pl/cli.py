"""``python -m hnn_pl {fit,validate,test,predict} --config X.yaml`` (LightningCLI)."""

from __future__ import annotations

import logging
import warnings

from lightning.pytorch import LightningDataModule, LightningModule
from lightning.pytorch.cli import ArgsType, LightningCLI

from hnn_pl.config_paths import resolve_config_args


class _DropTips(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "LitLogger" not in record.getMessage() and "💡" not in record.getMessage()


def quiet_lightning() -> None:
    """Drop Lightning's advertising tip, its pytree ``LeafSpec`` FutureWarning and its
    warning about ``args`` given beside ``sys.argv`` (we pass the resolved argv)."""
    logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_DropTips())
    warnings.filterwarnings("ignore", message=".*LeafSpec.*", category=FutureWarning)
    warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter is intended.*")
    warnings.filterwarnings("ignore", message=".*The dirpath has changed.*")


class HNNCLI(LightningCLI):
    """LightningCLI that links the DataModule's ``state_dim`` to the model's ``input_dim``."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.state_dim", "model.init_args.input_dim", apply_on="instantiate")


def cli_main(args: ArgsType = None, run: bool = True) -> HNNCLI:
    """Run the CLI on ``args`` (``sys.argv[1:]`` when ``None``); returns the CLI object."""
    import sys

    quiet_lightning()
    args = resolve_config_args(sys.argv[1:] if args is None else list(args))
    return HNNCLI(
        LightningModule,
        LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        args=args,
        run=run,
        save_config_kwargs={"overwrite": True},
    )
