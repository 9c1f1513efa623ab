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


class TouchRefused(CoreError):  # noqa: N818
    """The observation source refused to perform one action (a device refused the touch).

    Raised by a touch source of an evaluation trial (e.g. the rig's, when a servo
    overloads); :func:`core.evaluation.trial_engine.run_trial` ends only that trial and records it
    as refused. Anything else an observation source raises ends the whole evaluation.

    Attributes:
        error: What refused it, e.g. the device error's class name (``"ServoHardwareError"``).
        reason: The device's message.
    """

    def __init__(self, error: str, reason: str) -> None:
        super().__init__(f"{error}: {reason}")
        self.error = error
        self.reason = reason

    def __reduce__(self) -> tuple[type[TouchRefused], tuple[str, str]]:
        return (type(self), (self.error, self.reason))
