"""The last-layer Laplace posterior (Eq. 8) and the ensemble policy over it (Eq. 9)."""

from torchrl_dual.modules.laplace.laplace_ensemble_actor import LaplaceEnsembleActor
from torchrl_dual.modules.laplace.last_layer_laplace import LastLayerLaplace
from torchrl_dual.modules.laplace.latent_ensemble_actor import LatentEnsembleActor

__all__ = ["LaplaceEnsembleActor", "LastLayerLaplace", "LatentEnsembleActor"]
