"""The reference policy server: ``python -m stubs.policy_server --port N`` or ``serve(config)``."""

from peer.envelope import ChunkSource, Proposal, chunk_frame
from stubs.policy_server.config import ServerConfig
from stubs.policy_server.faults import FaultConfig
from stubs.policy_server.policy import InsertionPolicy, LatencyModel
from stubs.policy_server.server import PolicyServer, ServerStats, serve

__all__ = [
    "ChunkSource", "FaultConfig", "InsertionPolicy", "LatencyModel", "PolicyServer", "Proposal",
    "ServerConfig", "ServerStats", "chunk_frame", "serve",
]
