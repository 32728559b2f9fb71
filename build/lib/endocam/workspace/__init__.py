"""Where the camera may be: the cone around the RCM, the floor and the wire's keep-out zone.

Below both ``control/`` (whose goals stay inside) and ``robot/`` (whose carriers keep the camera
inside): :mod:`~endocam.workspace.cone`, :mod:`~endocam.workspace.keepout` and
:mod:`~endocam.workspace.region` (``Workspace``, with its compiled queries).
"""

from endocam.workspace.cone import CONE_BASE_RADIUS, CONE_HEIGHT, ConeWorkspace
from endocam.workspace.keepout import KeepOut, KeepOutState
from endocam.workspace.region import Workspace, WorkspaceState

__all__ = [
    "CONE_BASE_RADIUS",
    "CONE_HEIGHT",
    "ConeWorkspace",
    "KeepOut",
    "KeepOutState",
    "Workspace",
    "WorkspaceState",
]
