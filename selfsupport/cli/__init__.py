"""The ``selfsupport`` command line: :mod:`selfsupport.cli.common` holds the parser, the shared
helpers and ``solve``/``check``/``demo``; every other module of this package adds its commands
(its ``COMMANDS`` dict), listed by :func:`command_index` without importing the module."""
import os

# OpenBLAS's idle threads spin for 2^28 cycles (~0.1 s) after each call before they sleep; numpy,
# scipy and cvxopt each load their own copy, and that spinning cost ~0.08 CPU s of every command's
# start. 2^4 cycles: they sleep at once, and the next call wakes them. Set before numpy loads (it is
# read then); a value the user set stays.
os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")

from selfsupport.cli.common import (
                                  COMMANDS,
                                  EXIT_CODES,
                                  IPOPT_HINT_MAX,
                                  STATUS_EXIT,
                                  STATUS_HINT,
                                  Command,
                                  CommandEntry,
                                  build_parser,
                                  command_index,
                                  console_main,
                                  discover_commands,
                                  load_command,
                                  load_scene,
                                  main,
                                  summary_rows,
)

__all__ = ["COMMANDS", "EXIT_CODES", "IPOPT_HINT_MAX", "STATUS_EXIT", "STATUS_HINT", "Command", "CommandEntry",
           "build_parser", "command_index", "console_main", "discover_commands", "load_command", "load_scene", "main",
           "summary_rows"]
