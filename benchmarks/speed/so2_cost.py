"""What an SO2 critic update and OFF2ON's balanced replay cost here, against IQL's critic.

    python -m benchmarks.speed.so2_cost                  # ~1 minute
    python -m benchmarks.speed.so2_cost --updates 50 --members 10 --width 256

Times, on one thread (CPU time), with the same MLP widths and depths for both critics:

* one :class:`~torchrl_dual.objectives.SO2QLoss` update (``E`` members, a tanh-Gaussian
  actor sampling ``a'``, smoothed target, backward, Adam, TorchRL ``SoftUpdate``);
* one TorchRL ``IQLLoss`` critic update (``qvalue`` + ``value`` losses of the twin Q and
  V networks, backward, Adam, ``SoftUpdate``), the critic the recipe uses today;
* OFF2ON's per-update extras: a :class:`~torchrl_dual.data.BalancedReplayBuffer` sample
  over ``--replay-size`` transitions, a :class:`~torchrl_dual.objectives.DensityRatioLoss`
  step and a priority refresh.

SO2 runs 10 critic updates per environment step (UTD 10), so its online phase costs about
``10 x (SO2 update + replay extras)`` per step where IQL's costs ``utd_ratio x`` one IQL
update. Prints a Markdown table and the ratio.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import Bounded, LazyTensorStorage, ReplayBuffer
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import IQLLoss, SoftUpdate

from benchmarks.speed.ant_controller_cost import batch
from benchmarks.speed.families import time_steps
from torchrl_dual.data import BalancedReplayBuffer
from torchrl_dual.objectives import DensityRatioLoss, SO2QLoss, make_density_ratio_network

OBS_DIM, ACT_DIM = 8, 2  # PointMaze: observation (4) + desired and achieved goal (2 + 2)


def actor(width: int, depth: int) -> ProbabilisticActor:
    net = nn.Sequential(
        MLP(OBS_DIM, 2 * ACT_DIM, num_cells=[width] * depth), NormalParamExtractor()
    )
    return ProbabilisticActor(
        TensorDictModule(net, ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        return_log_prob=True,
    )


def qvalue(width: int, depth: int) -> ValueOperator:
    return ValueOperator(
        MLP(OBS_DIM + ACT_DIM, 1, num_cells=[width] * depth), in_keys=["observation", "action"]
    )


def transitions(size: int) -> TensorDict:
    return batch(size, OBS_DIM, ACT_DIM)


def optimise(loss_value: Callable[[], torch.Tensor], module: nn.Module, target=None):
    optimizer = torch.optim.Adam(module.parameters(), lr=3e-4)

    def step() -> None:
        value = loss_value()
        optimizer.zero_grad()
        value.backward()
        optimizer.step()
        if target is not None:
            target.step()

    return step


def so2_update(args, data: TensorDict) -> Callable[[], None]:
    loss = SO2QLoss(
        actor(args.width, args.depth),
        qvalue(args.width, args.depth),
        action_spec=Bounded(-1.0, 1.0, (ACT_DIM,)),
        num_qvalue_nets=args.members,
        entropy_coef=0.2,
    )
    return optimise(lambda: loss(data)["loss_qvalue"], loss, SoftUpdate(loss, tau=0.005))


def iql_update(args, data: TensorDict) -> Callable[[], None]:
    value = ValueOperator(MLP(OBS_DIM, 1, num_cells=[args.width] * args.depth), ["observation"])
    loss = IQLLoss(actor(args.width, args.depth), qvalue(args.width, args.depth), value)

    def total() -> torch.Tensor:
        return loss.qvalue_loss(data)[0] + loss.value_loss(data)[0]

    return optimise(total, loss, SoftUpdate(loss, tau=0.005))


def balanced_replay_extras(args) -> Callable[[], None]:
    offline = ReplayBuffer(storage=LazyTensorStorage(args.replay_size))
    offline.extend(transitions(args.replay_size))
    network = make_density_ratio_network(OBS_DIM, ACT_DIM, num_cells=[args.width] * 2)
    replay = BalancedReplayBuffer(
        offline, online_capacity=10_000, batch_size=args.batch_size, ratio_network=network
    )
    replay.extend(transitions(10_000))
    ratio_loss = DensityRatioLoss(network)
    ratio_step = optimise(
        lambda: ratio_loss(replay.ratio_batch())["loss_density_ratio"], ratio_loss
    )

    def step() -> None:
        batch = replay.sample()
        ratio_step()
        replay.refresh_priorities(batch)

    return step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--updates", type=int, default=50)
    parser.add_argument("--members", type=int, default=10)
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--depth", type=int, default=2)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--replay-size", type=int, default=1_000_000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    data = transitions(args.batch_size)
    so2_ms = time_steps(so2_update(args, data), args.updates)
    iql_ms = time_steps(iql_update(args, data), args.updates)
    extras_ms = time_steps(balanced_replay_extras(args), args.updates)
    size = f"{args.depth} x {args.width}, batch {args.batch_size}"
    print(f"CPU ms per update, one thread ({size}):\n")
    print("| update | ms | updates/s |")
    print("|---|---:|---:|")
    for label, ms in (
        (f"SO2 critic, E = {args.members}", so2_ms),
        ("IQL critic (twin Q + V)", iql_ms),
        (f"balanced replay extras, N = {args.replay_size:,}", extras_ms),
    ):
        print(f"| {label} | {ms:.2f} | {1000 / ms:.1f} |")
    print(f"\nSO2 / IQL critic update (ratio of mean CPU ms): {so2_ms / iql_ms:.2f}x")
    print(f"SO2 + balanced replay / IQL critic update: {(so2_ms + extras_ms) / iql_ms:.2f}x")


if __name__ == "__main__":
    main()
