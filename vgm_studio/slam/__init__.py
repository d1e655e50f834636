"""Stage 5: scans → a graph-SLAM run: odometry, keyframes, matched and validated edges.

``pipeline.run_slam`` runs it; ``report`` turns the result into relation errors, maps and the
JSON summary. Nothing is imported here, so that importing a config or the edge type does
not pull in the whole pipeline (and its model and gtsam imports).
"""
