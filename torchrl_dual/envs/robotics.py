"""Gymnasium-Robotics, imported once and registered with Gymnasium, without its Adroit notice.

Gymnasium-Robotics 1.2.1-1.4.2 prints, on import, a notice (from ``farama_notifications``)
that its ``AdroitHand{Relocate,Hammer,Door}Dense-v1`` rewards changed in 1.2.1. Every
PointMaze or AntMaze run and each of its collector workers printed it; none of these uses
those envs (``env=adroit`` does: the D4RL data sets' Adroit envs are the dense
``AdroitHand*-v1``, whose reward change docs/reproducing.md describes; the notice says
nothing more).
:func:`register_robotics_envs` drops that one line from what the import writes to stderr
and passes everything else on.
"""

from __future__ import annotations

import contextlib
import io
import sys
from types import ModuleType

import gymnasium as gym

_ADROIT_NOTICE = "environment's reward functions were updated in v1.2.1"


def register_robotics_envs() -> ModuleType:
    """Imports ``gymnasium_robotics``, registers its envs with Gymnasium and returns the module.

    Its notice line is filtered out of stderr the first time.

    Examples:
        >>> import gymnasium as gym
        >>> robotics = register_robotics_envs()
        >>> "PointMaze_UMaze-v3" in gym.registry
        True
    """
    if "gymnasium_robotics" in sys.modules:
        module = sys.modules["gymnasium_robotics"]
    else:
        with contextlib.redirect_stderr(io.StringIO()) as captured:
            import gymnasium_robotics as module
        kept = [line for line in captured.getvalue().splitlines() if _ADROIT_NOTICE not in line]
        if kept:
            print("\n".join(kept), file=sys.stderr)
    gym.register_envs(module)
    return module
