r"""The one workaround for a tensordict 0.14 slowdown on every ``TensorDictModule`` call.

``TensorDictModule._write_to_tensordict`` stores each output as
``TensorDict.from_any(tensor)``. For a plain tensor ``from_any`` falls through every
conversion it knows and returns the tensor itself, but on the way it calls
``importlib.util.find_spec("pandas")``: without pandas imported, a scan of ``sys.path``
(a ``stat`` per entry) for every output of every module call. TorchRL's losses and
actors are ``TensorDictModule``\s, so an IQL update pays it about eight times:
9.5 % of its CPU time on this project's 2-core machine (docs/benchmarks.md).

:func:`install` puts a first check in front of ``TensorDictBase.from_any``: an object
of type ``torch.Tensor`` is returned as it is, which is what ``from_any`` returns for it;
anything else goes to tensordict's own ``from_any``. The recipe's runs and
:class:`~torchrl_dual.trainers.DUALTrainer` install it; set
``TORCHRL_DUAL_PATCH_TENSORDICT=0`` to keep tensordict as it is.
``tests/test_tensordict_patch.py`` fails once tensordict stops scanning, so that the
workaround can go.
"""

from __future__ import annotations

import os
from typing import Any

import torch
from tensordict import TensorDictBase

OPT_OUT = "TORCHRL_DUAL_PATCH_TENSORDICT"
"""Set to ``0`` to leave ``TensorDictBase.from_any`` untouched."""

_ORIGINAL = TensorDictBase.__dict__["from_any"]


def _from_any(cls: type, obj: Any, *args: Any, **kwargs: Any) -> Any:
    if type(obj) is torch.Tensor:  # from_any's answer for a plain tensor, without its scan
        return obj
    return _ORIGINAL.__func__(cls, obj, *args, **kwargs)


def installed() -> bool:
    """Whether ``TensorDictBase.from_any`` has the plain-tensor shortcut."""
    return getattr(TensorDictBase.__dict__["from_any"], "__func__", None) is _from_any


def install() -> bool:
    """Installs the plain-tensor shortcut in front of ``TensorDictBase.from_any``.

    Installs it once (later calls do nothing), unless
    ``TORCHRL_DUAL_PATCH_TENSORDICT=0``. Returns whether it is installed.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> install()
        True
        >>> value = torch.zeros(2)
        >>> TensorDict.from_any(value) is value
        True
        >>> TensorDict.from_any({"a": value}).batch_size  # the rest is tensordict's
        torch.Size([])
    """
    if os.environ.get(OPT_OUT, "1") == "0":
        return installed()
    if not installed():
        TensorDictBase.from_any = classmethod(_from_any)
    return True


def uninstall() -> None:
    """Gives ``TensorDictBase.from_any`` back its tensordict definition."""
    TensorDictBase.from_any = _ORIGINAL
