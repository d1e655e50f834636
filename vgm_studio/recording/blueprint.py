"""The viewer layout a debugging engineer wants: the map, the edge inspector, the metrics."""

from __future__ import annotations

import rerun.blueprint as rrb

from vgm_studio.recording.paths import INSPECTOR, METRICS, TIMELINE, VERDICT, VGM, WORLD


def blueprint() -> rrb.Blueprint:
    """Map on the left (history up to the time cursor); VGM, verdict and metrics on the right."""
    history = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(
                name="map",
                origin=WORLD,
                contents=f"{WORLD}/**",
                time_ranges=[history],
            ),
            rrb.Vertical(
                rrb.Spatial2DView(name="edge inspector (VGM)", origin=VGM),
                rrb.TextDocumentView(name="verdict", origin=VERDICT),
                rrb.TimeSeriesView(name="metrics", origin=METRICS),
                rrb.TimeSeriesView(name="p(success)", origin=f"{INSPECTOR}/p_success"),
                row_shares=[3, 1, 2, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )
