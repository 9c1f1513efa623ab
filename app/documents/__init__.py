"""File formats, one concept per module.

- :mod:`app.documents.training_csv`: the training CSV (read, write, append touch by touch).
- :mod:`app.documents.model`: the model document ("activetouch-model/1").
- :mod:`app.documents.posterior`: its ``posterior`` field (also stored on a model row), and
  conditioning a GP exactly as it records.
- :mod:`app.documents.noise_model`: its ``noise_model`` field (the observation transform).
- :mod:`app.documents.json_values`: checks of free-form JSON a client sends (finite numbers,
  valid text, bounded nesting), used by the model document and a touch's trajectory record.
- :mod:`app.documents.errors`: :class:`~app.documents.errors.DocumentError`, raised by all of them.

Import from the concept module (``from app.documents.model import model_to_document``).
"""
