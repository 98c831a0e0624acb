"""``min_k Q_k(s, a)`` of a critic ensemble: one vmapped call against a loop over members.

    python -m benchmarks.speed.ensemble_eval                 # ~30 s
    python -m benchmarks.speed.ensemble_eval --members 2 10 --reps 100

:class:`~torchrl_dual.objectives.WeightedMAPActorLoss` reads ``min_k Q_k`` of the base
critic (IQL's twin Q, Cal-QL's twin Q, SO2's 10 members) on every actor update, with
gradients to the action under the ``sac`` weighting. It evaluates all members in one call
vmapped over their stacked weights (TorchRL's ``_vmap_func``, as TorchRL's losses do);
this script times that against the former loop (one ``to_module`` swap and call per
member), forward and backward to the action, rounds alternating in one process, and prints
the medians (wall clock, one thread) and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ValueOperator

from torchrl_dual.modules import LinearHeadActor
from torchrl_dual.objectives import WeightedMAPActorLoss


def q_network(obs_dim: int, action_dim: int, width: int) -> ValueOperator:
    mlp = MLP(obs_dim + action_dim, 1, num_cells=[width, width], activation_class=nn.ReLU)
    return ValueOperator(mlp, in_keys=["observation", "action"])


def loop_min(network: nn.Module, params: TensorDict, td: TensorDict) -> torch.Tensor:
    """The former evaluation: each member's weights swapped in, one call each."""
    outputs = []
    for member in params.unbind(0):
        with member.to_module(network):
            outputs.append(network(td.clone(False)).get("state_action_value"))
    return torch.stack(outputs).min(0).values.squeeze(-1)


def median_ms(fn: Callable[[], torch.Tensor], action: torch.Tensor, reps: int) -> float:
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn().sum().backward()
        times.append(time.perf_counter() - start)
        action.grad = None
    return 1e3 * statistics.median(times)


def compare(members: int, args: argparse.Namespace) -> tuple[float, float]:
    """Median ms of the loop and of the vmapped evaluation over ``args.rounds`` rounds."""
    obs_dim, action_dim = 8, 2  # PointMaze
    torch.manual_seed(0)
    nets = [q_network(obs_dim, action_dim, args.width) for _ in range(members)]
    params = TensorDict.from_modules(*nets, as_module=True).detach()
    actor = LinearHeadActor(MLP(obs_dim, action_dim, num_cells=[args.width]), action_dim)
    loss = WeightedMAPActorLoss(
        actor,
        qvalue_network=nets[0],
        qvalue_params=params,
        weighting="sac",
        action_spec=Bounded(-1.0, 1.0, shape=(action_dim,)),
    )
    action = torch.rand(args.batch, action_dim, requires_grad=True)
    td = TensorDict(
        {"observation": torch.randn(args.batch, obs_dim), "action": action}, [args.batch]
    )
    torch.testing.assert_close(loss.q_value(td), loop_min(nets[0], params, td))
    loop, vmapped = [], []
    for _ in range(args.rounds):
        loop.append(median_ms(lambda: loop_min(nets[0], params, td), action, args.reps))
        vmapped.append(median_ms(lambda: loss.q_value(td), action, args.reps))
    return statistics.median(loop), statistics.median(vmapped)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--members", type=int, nargs="+", default=[2, 10])
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--reps", type=int, default=50, help="timed calls per round")
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print("| members | loop (ms) | vmapped (ms) | loop / vmapped (ratio of medians) |")
    print("|---:|---:|---:|---:|")
    for members in args.members:
        loop, vmapped = compare(members, args)
        print(f"| {members} | {loop:.2f} | {vmapped:.2f} | {loop / vmapped:.2f}x |", flush=True)


if __name__ == "__main__":
    main()
