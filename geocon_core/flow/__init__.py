"""Dense optical flow: the classical DIS backend and RAFT-small.

:mod:`.dense` holds the backends (:class:`DisFlow`, :class:`RaftFlow`), forward-backward checks and
flows composed over several frames (:class:`FlowChain`); :mod:`.raft` is the RAFT-small network,
loaded from a checkpoint the user supplies. It imports torch, so it is not re-exported here:
:class:`RaftFlow` loads it when built, and code that needs the network imports
``geocon_core.flow.raft`` itself.
"""

from __future__ import annotations

from .dense import (
    DIS_PRESETS,
    FLOW_BACKENDS,
    DisFlow,
    FlowBackend,
    FlowChain,
    FlowField,
    RaftFlow,
    chained_flow,
    forward_backward,
    make_flow_backend,
)

__all__ = [
    "DIS_PRESETS",
    "DisFlow",
    "FLOW_BACKENDS",
    "FlowBackend",
    "FlowChain",
    "FlowField",
    "RaftFlow",
    "chained_flow",
    "forward_backward",
    "make_flow_backend",
]
