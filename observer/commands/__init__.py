"""Subcommands of the ``dcobserver`` CLI, one module each (see :mod:`observer.cli`).

Start with :mod:`observer.cli` (the command table); each module here has
``configure(parser)`` and ``main(args)``. Import rule: the CLI sits on top and
may import anything; nothing but :mod:`observer.cli` imports it (checked by
``tests/test_architecture.py``).
"""
