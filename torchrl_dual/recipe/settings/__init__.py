"""The recipe's config schema, its rules and its errors: what is checked before anything
runs. Nothing here imports torch or TorchRL, so a bad config value is reported at once."""
