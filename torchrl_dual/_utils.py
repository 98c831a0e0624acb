"""Helpers every module of the package shares.

Reading a required tensordict entry (for any reader, and for a loss with its ``set_keys``
fix), writing one on the action path, and asking whether the current exploration mode is
deterministic.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.envs.utils import ExplorationType, exploration_type

DETERMINISTIC_MODES = (
    ExplorationType.DETERMINISTIC,
    ExplorationType.MODE,
    ExplorationType.MEDIAN,
    ExplorationType.MEAN,
)
"""Exploration types that ask for the policy's central action: for the Gaussian policies
here (Eq. 9-10) the mode, the median and the mean are one point."""


def host_reads_allowed() -> bool:
    """Whether a check may read a tensor's value back to the host now.

    Not while ``torch.compile`` traces (a graph break) nor while a CUDA graph is
    captured (a sync there invalidates the capture). Eager calls keep every input check.

    Examples:
        >>> host_reads_allowed()
        True
    """
    if torch.compiler.is_compiling():
        return False
    return not (torch.cuda.is_available() and torch.cuda.is_current_stream_capturing())


def check_finite(value: Tensor, role: str, fix: str) -> None:
    """Raises a ``ValueError`` if ``value`` holds a NaN or inf entry.

    The message names ``role``, the count of NaN/inf entries and ``fix``. Skipped where
    :func:`host_reads_allowed` is ``False``.

    Examples:
        >>> import torch
        >>> check_finite(torch.tensor([1.0, float("nan")]), "action", "clean the data first.")
        Traceback (most recent call last):
        ...
        ValueError: action holds 1 NaN/inf entries; clean the data first.
    """
    if host_reads_allowed() and not bool(torch.isfinite(value).all()):
        bad = int((~torch.isfinite(value)).sum())
        raise ValueError(f"{role} holds {bad} NaN/inf entries; {fix}")


def require_finite(value: Tensor, what: str, tensordict: TensorDictBase) -> None:
    """Raises a ``ValueError`` if ``value`` is not finite, saying where its batch first is not.

    The message names ``what`` and where ``tensordict`` (the batch ``value`` was
    computed from) first holds a NaN or inf. Skipped where :func:`host_reads_allowed` is
    ``False``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> td = TensorDict(observation=torch.tensor([[1.0], [float("inf")]]), batch_size=[2])
        >>> require_finite(td["observation"].sum(), "the loss", td)
        Traceback (most recent call last):
        ...
        ValueError: the loss holds a NaN or inf; the batch's 'observation' is not finite at batch index 1: clean the data.
    """
    if host_reads_allowed() and not bool(torch.isfinite(value).all()):
        raise ValueError(f"{what} holds a NaN or inf; {first_non_finite(tensordict)}")


def first_non_finite(tensordict: TensorDictBase) -> str:
    """Where a batch first holds a NaN or inf, as a sentence for an error message.

    The key and the batch index of its first non-finite float entry, or, for a finite
    batch, that the weights diverged.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"next": {"reward": torch.tensor([[0.0], [float("nan")]])}}, [2])
        >>> first_non_finite(td)
        "the batch's ('next', 'reward') is not finite at batch index 1: clean the data."
    """
    for key, value in tensordict.items(True, True):
        if not value.is_floating_point():
            continue
        bad = ~torch.isfinite(value.reshape(*value.shape[: tensordict.batch_dims], -1))
        if bool(bad.any()):
            index = [int(i) for i in bad.any(-1).nonzero()[0]]
            where = index[0] if len(index) == 1 else tuple(index)
            return f"the batch's {key!r} is not finite at batch index {where}: clean the data."
    return "the batch is finite, so the weights diverged: lower the learning rate."


def read_key(tensordict: TensorDictBase, key: NestedKey, reader: str, fix: str = "") -> Tensor:
    """``tensordict[key]``, or a ``KeyError`` naming ``reader``, the keys present and ``fix``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> read_key(TensorDict(a=torch.zeros(2), batch_size=[2]), "a", "me").shape
        torch.Size([2])
        >>> read_key(TensorDict(a=torch.zeros(2), batch_size=[2]), "b", "me", "Add it.")
        Traceback (most recent call last):
        ...
        KeyError: "me reads 'b', which the input lacks; it holds ['a']. Add it."
    """
    if type(tensordict) is TensorDict and type(key) is str:  # the action path's case
        value = tensordict._get_str(key, None)  # what get() ends in, without the key parsing
    else:
        value = tensordict.get(key, None)
    if value is None:
        message = (
            f"{reader} reads {key!r}, which the input lacks; it holds "
            f"{sorted(map(str, tensordict.keys(True, True)))}."
        )
        raise KeyError(f"{message} {fix}" if fix else message)
    return value


def write_key(tensordict: TensorDictBase, key: NestedKey, value: Tensor) -> None:
    """Writes ``tensordict.set(key, value)``, faster on the action path.

    A few times cheaper for the common case: a plain ``TensorDict``, a string key and a
    tensor whose leading dims are the batch size, on the tensordict's device (what
    TorchRL's env steps do with ``_set_str(..., validated=True)``). Anything else, or a
    value that fails those checks, goes through ``set`` and its validation and errors.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> td = TensorDict(batch_size=[2])
        >>> write_key(td, "loc", torch.zeros(2, 3))
        >>> td["loc"].shape
        torch.Size([2, 3])
        >>> write_key(td, "loc", torch.zeros(5, 3))  # wrong batch dims: set()'s error
        Traceback (most recent call last):
        ...
        RuntimeError: batch dimension mismatch, got self.batch_size=torch.Size([2]) and value.shape=torch.Size([5, 3]).
    """
    if (
        type(tensordict) is TensorDict
        and type(key) is str
        and isinstance(value, Tensor)
        and value.shape[: tensordict.batch_dims] == tensordict.batch_size
        and (tensordict.device is None or value.device == tensordict.device)
    ):
        tensordict._set_str(key, value, inplace=False, validated=True)
    else:
        tensordict.set(key, value)


def read_loss_input(tensordict: TensorDictBase, key: NestedKey, role: str) -> Tensor:
    """A loss module's input: :func:`read_key` whose fix names ``loss.set_keys(role=...)``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> read_loss_input(TensorDict(obs=torch.zeros(2), batch_size=[2]), "obs", "observation")
        tensor([0., 0.])
    """
    return read_key(
        tensordict,
        key,
        f"The loss's {role} entry",
        f"Rename the entry or call loss.set_keys({role}=...).",
    )


def is_deterministic() -> bool:
    """Whether the current TorchRL exploration type asks for the mean action.

    ``DETERMINISTIC``, ``MODE``, ``MEDIAN`` or ``MEAN`` do; ``RANDOM`` and unset mean
    sampling.

    Examples:
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> with set_exploration_type(ExplorationType.DETERMINISTIC):
        ...     is_deterministic()
        True
        >>> is_deterministic()
        False
    """
    return exploration_type() in DETERMINISTIC_MODES


def one_hot_at(index: Tensor, like: Tensor, dim: int) -> Tensor:
    """A one-hot tensor shaped and typed like ``like``, 1 where ``index`` points along ``dim``.

    ``index`` has ``like``'s shape with size 1 at ``dim``. A scatter, not
    :func:`torch.nn.functional.one_hot`, which reads the indices back to the host to
    check their range (a device sync in every acting step or update).

    Examples:
        >>> scores = torch.tensor([[0.1, 0.7, 0.2], [0.5, 0.1, 0.4]])
        >>> one_hot_at(scores.argmax(-1, keepdim=True), scores, -1)
        tensor([[0., 1., 0.],
                [1., 0., 0.]])
    """
    return torch.zeros_like(like).scatter_(dim, index, 1.0)
