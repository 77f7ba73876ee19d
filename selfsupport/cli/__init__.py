"""The ``selfsupport`` command line: :mod:`selfsupport.cli.common` holds the parser, the shared
helpers and ``solve``/``check``/``demo``; every other module of this package adds its commands
(its ``COMMANDS`` dict), listed by :func:`command_index` without importing the module."""
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
                                  discover_commands,
                                  load_command,
                                  load_scene,
                                  main,
                                  summary_rows,
)

__all__ = ["COMMANDS", "EXIT_CODES", "IPOPT_HINT_MAX", "STATUS_EXIT", "STATUS_HINT", "Command", "CommandEntry",
           "build_parser", "command_index", "discover_commands", "load_command", "load_scene", "main", "summary_rows"]
