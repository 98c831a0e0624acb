"""The recipe's config schema, its rules and its errors: what is checked before anything runs.

Nothing here imports torch or TorchRL, so a bad config value is reported at once.

Importing the package registers the ``${reference:<key>,<default>}`` interpolation the
config files use (:mod:`torchrl_dual.recipe.settings.references`).
"""

from torchrl_dual.recipe.settings.references import register_reference_resolver

register_reference_resolver()
