"""Stage 7: poses and scans → occupancy grid maps (log-odds, one ray per beam) and pictures."""
