"""VGM Studio: label, validate and debug 2D LiDAR scan-matching edges.

The package folders follow the data flow, one way; each imports only from those above it
in this list's later rows (the command line at the top, ``core/`` at the bottom):

    tools/       the ``vgm-studio`` command line: parse, call one service, print
    services/    what each command does, as one call (candidates, slam, train/eval, info)
    studio/      the viser labeling app; ``studio/serve.py`` runs it with the trainer beside it
    workspace.py a workspace filled from a log or an edges file, and scored by a model
    trainer/     the background trainer: labels in, model versions and p(success) out
    recording/   a SLAM run → a rerun recording (stage 8)
    slam/        a whole SLAM run: odometry, keyframes, loops, validation (stage 5)
    graph/       the gtsam pose graph, robust kernels, relation errors (stage 6)
    maps/        occupancy grid maps and their pictures (stage 7)
    model/       edge → p(success): the model registry, networks, checkpoints, training (stage 4)
    labels/      the workspace's label store, votes, labels out and in
    vgm/         edge → Validation Grid Map, and its pictures (stage 3)
    matching/    scans → candidate edges: kiss-icp + 2D refinement, reference labels (stage 2)
    simulation/  corridor worlds → CARMEN logs with ground truth
    datasets/    log → scans: CARMEN, ROS bags, Freiburg relations; a log with its reference
    errors.py    the one-line errors a user can fix, and how a process exits on them
    core/        SE(2) math, content hashes, the default p(success) cut; no I/O of its own
"""

__version__ = "0.1.0"
