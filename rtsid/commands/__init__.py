"""Subcommands of the ``rtsid`` CLI (argument parsing only; the work lives in the packages)."""
