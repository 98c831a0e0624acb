"""What a checkpoint holds of a critic (``critics._CriticState``): checkpoints of earlier
versions still resume (the IQL critic's Q networks before they came from
``critics.q_network``, keys ``...module.mlp.*``), and a state whose keys do not fit is
refused, which TorchRL's own ``load_state_dict`` does not do."""

from __future__ import annotations

import pytest

from torchrl_dual.recipe.parts import critics
from torchrl_dual.recipe.settings.parts import IQLCriticSettings

TINY = ("algo=iql", "env=frozenlake", "budget.offline_updates=10", "budget.online_frames=100")
TINY += ("budget.frames_per_batch=50", "budget.eval_every=100", "budget.eval_episodes=1")


def _iql_critic():
    settings = IQLCriticSettings(
        name="iql",
        hidden=8,
        depth=2,
        lr=3e-4,
        discount=0.99,
        target_update_tau=0.005,
        actor_weighting="advantage",
        expectile=0.7,
    )
    return critics.make_iql_critic(settings, 4, 2)


def test_torchrl_s_loss_module_skips_an_unknown_parameter_key_without_a_word():
    """The upstream behaviour ``_CriticState`` guards against (TorchRL 0.14.1): if this
    fails, TorchRL now refuses the key itself and the check in ``_CriticState`` is only a
    clearer message."""
    loss = _iql_critic().loss
    state = loss.state_dict()
    key = next(k for k in state if k.startswith("qvalue_network_params.module.0."))
    renamed = {k.replace("module.0.", "module.9.") if k == key else k: v for k, v in state.items()}
    before = loss.qvalue_network_params.clone()
    assert str(loss.load_state_dict(renamed, strict=True)) == "<All keys matched successfully>"
    assert (loss.qvalue_network_params == before).all()  # nothing was loaded into module.0


@pytest.mark.parametrize("keep_actor", [True, False])
def test_a_critic_state_with_a_foreign_key_is_refused_naming_it(keep_actor):
    critic = _iql_critic()
    saved = critics._CriticState(critic.loss, keep_actor=keep_actor)
    state = saved.state_dict()
    key = next(k for k in state if k.startswith("qvalue_network_params.module.0."))
    foreign = {k.replace("module.0.", "module.9.") if k == key else k: v for k, v in state.items()}
    with pytest.raises(RuntimeError, match="critic state does not fit: missing") as error:
        saved.load_state_dict(foreign)
    assert key in str(error.value) and key.replace("module.0.", "module.9.") in str(error.value)
    saved.load_state_dict(state)  # its own state loads
