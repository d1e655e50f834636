"""Stage 2: scans → candidate edges. kiss-icp registration, 2D refinement, reference labels."""
