"""Stage 6: edges → a gtsam Pose2 pose graph, its robust optimisation, and relation errors."""

from vgm_studio.graph.pose_graph import GraphEdge, OptimizeResult, RunningEstimate, optimize

__all__ = ["GraphEdge", "OptimizeResult", "RunningEstimate", "optimize"]
