"""Reading a required entry of a tensordict with an error that names what is there."""

from __future__ import annotations

from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import Tensor


def read_key(tensordict: TensorDictBase, key: NestedKey, reader: str, fix: str = "") -> Tensor:
    """``tensordict[key]``, or a ``KeyError`` naming ``reader``, the keys present and ``fix``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> read_key(TensorDict(a=torch.zeros(2), batch_size=[2]), "a", "me").shape
        torch.Size([2])
    """
    value = tensordict.get(key, None)
    if value is None:
        message = (
            f"{reader} reads {key!r}, which the input lacks; it holds "
            f"{sorted(map(str, tensordict.keys(True, True)))}."
        )
        raise KeyError(f"{message} {fix}" if fix else message)
    return value
