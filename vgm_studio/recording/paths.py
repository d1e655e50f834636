"""Entity paths and timelines of a recording: one place, so the writer, the blueprint and the
tests agree."""

TIMELINE = "keyframe"
EDGE_TIMELINE = "inspected_edge"

WORLD = "/world"
MAPS = f"{WORLD}/maps"
TRAJECTORIES = f"{WORLD}/trajectory"
SCAN = f"{WORLD}/scan"
ROBOT = f"{WORLD}/robot"
EDGES_KEPT = f"{WORLD}/edges/kept"
EDGES_REJECTED = f"{WORLD}/edges/rejected"
EDGES_INCONSISTENT = f"{WORLD}/edges/inconsistent"
INSPECTED = f"{WORLD}/edges/inspected"

INSPECTOR = "/inspector"
VGM = f"{INSPECTOR}/vgm"
VERDICT = f"{INSPECTOR}/verdict"
METRICS = "/metrics"
