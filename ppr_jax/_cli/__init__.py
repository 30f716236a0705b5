"""The command-line wing: one module per command (parse, one library call, writers), the shared
options in `_common.py`, the parser and entry point in `_main.py`."""

from ._common import model_from_args
from ._main import build_parser, main

__all__ = ["build_parser", "main", "model_from_args"]
