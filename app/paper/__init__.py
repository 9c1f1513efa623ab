"""Reproductions of the paper's experiments, composed from ``core`` and rendered for the CLI."""
