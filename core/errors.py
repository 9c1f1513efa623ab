"""Errors raised by :mod:`core`.

Every error raised on purpose by this package derives from :class:`CoreError`, so callers
(the CLI, the web app) can map them to a clear message without catching bare exceptions.
"""

from __future__ import annotations


class CoreError(Exception):
    """Base class of every error raised by :mod:`core`."""


class InvalidInputError(CoreError, ValueError):
    """An argument has the wrong shape, a non-finite value, or is otherwise unusable.

    The message names the argument, what was received and what was expected.
    """


class NotPositiveDefiniteError(CoreError, ArithmeticError):
    """A covariance or Gram matrix stayed non positive definite after the jitter ladder."""


class NotFittedError(CoreError):
    """A model was used before it was fitted."""


class ConvergenceError(CoreError):
    """An optimiser failed on every start."""
