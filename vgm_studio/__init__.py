"""VGM Studio: label, validate and debug 2D LiDAR scan-matching edges.

The package folders follow the data flow, one way:

    datasets/    log → scans            (CARMEN, ROS bags, Freiburg relations)
    simulation/  corridor worlds → logs (ray-cast ground truth)
    matching/    scans → candidate edges (kiss-icp + 2D refinement, reference labels)
    vgm/         edge → Validation Grid Map
    tools/       the ``vgm-studio`` command line

``core/`` holds the SE(2) math every stage shares and does no I/O.
"""

__version__ = "0.1.0"
