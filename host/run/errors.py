"""How a mesh render fails: every failure names its node, and a lost node is told apart
from a failing one because a re-plan can go on without it.
"""

NODE_LOSS = ("replan", "fail")  # what the host does when a node is lost (--on-node-loss)


class MeshError(RuntimeError):
    """The render failed on the mesh; the message names the node."""


class NodeLost(MeshError):
    """Node `node`'s link broke or it fell silent: a re-plan can go on without it."""

    def __init__(self, node: int, message: str):
        super().__init__(message)
        self.node = node
