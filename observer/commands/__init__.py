"""Subcommands of the ``dcobserver`` CLI, one module each (see :mod:`observer.cli`)."""
