"""The method, as pure computation (docs/method.md): four rooms over shared modules.

:mod:`core.gp` (the GP object manifold and its fit), :mod:`core.recognition` (the belief, the
object posterior, the policies, a recognition session), :mod:`core.selection` (choosing the
latent dimension), :mod:`core.evaluation` (running and scoring trials); shared by all:
:mod:`core.types`, :mod:`core.validation`, :mod:`core.errors`, :mod:`core.observation_transform`
and :mod:`core.features`. Each room's ``__init__`` is its public surface; docs/architecture.md
shows the layering.
"""
