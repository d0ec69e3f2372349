"""The command line: ``tendonkit COMMAND ...`` (see docs/cli.md).

The door of the cli room is :func:`main`.  The modules behind it: ``app`` (the parser, the
generic commands and the helpers every command shares), ``robot`` (plant, collect, export) and
``mpc`` (MPC in co-simulation).  The module with the parser is ``app``, not ``main``: the
console script ``tendonkit = tendonkit.cli:main`` names the function, and a submodule of the
same name would shadow it.
"""

from __future__ import annotations

from .app import main

__all__ = ["main"]
