"""Stage 5: scans → a graph-SLAM run: odometry, keyframes, matched and validated edges.

``pipeline.run_slam`` runs it; ``report`` turns the result into relation errors, maps and the
JSON summary. Nothing is imported here, so that ``graph``, ``maps`` and ``recording`` can
import the configs without pulling in the whole pipeline.
"""
