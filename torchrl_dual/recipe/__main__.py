"""``python -m torchrl_dual.recipe <overrides>``: the recipe, as ``torchrl-dual`` runs it."""

from torchrl_dual.recipe.cli import main

if __name__ == "__main__":
    main()
