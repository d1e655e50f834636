"""One tab's 3D view: the pair's nodes, which layers show, and a camera that frames each pair."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
import viser
from numpy.typing import NDArray

from vgm_studio.studio.view import (
    CUR_RGB,
    PREV_RGB,
    REFERENCE_RGB,
    EdgeView,
    PlacedPair,
    pose_marks,
)

_ONE_POINT = np.zeros((1, 3), dtype=np.float32)  # placeholder until an edge has a reference
# Points in screen pixels (viser sizes them in metres, so they are resized with each framing):
# over the VGM they are thinner than its 5 cm cells, so the cells show around them.
POINT_PIXELS = {
    "points and VGM": 1.4,
    "points and raw VGM cells": 1.4,
    "VGM only": 1.4,
    "points only": 2.5,
}
POINT_SIZE = 0.018  # metres, until the first framing
# Share of the view the pair may fill along its tighter axis; the rest is margin.
FILL = 0.85
_FALLBACK_FOV = math.radians(50.0)  # viser's default, until the browser reports its camera
_FALLBACK_ASPECT = 1.6
_FALLBACK_PIXELS = 800
_MIN_HEIGHT = 2.0  # metres: a tiny pair is not blown up past a few cells per pixel
CAMERA_HEIGHT = 10.0  # the fixed camera's height, in the fitted scene's units


class Layers(str, Enum):
    """What the 3D view shows; ``V`` steps through them in this order.

    The VGM cells' hues are mixed from the spread channels (``vgm.spread``) except in ``raw``,
    which mixes the cells' own values: one key away, for checking what the model sees.
    """

    both = "points and VGM"
    raw = "points and raw VGM cells"
    vgm = "VGM only"
    points = "points only"

    def next(self) -> Layers:
        members = list(Layers)
        return members[(members.index(self) + 1) % len(members)]


@dataclass(frozen=True)
class Framing:
    """The top-down view of a pair: a camera over (x, y) from ``height`` metres up.

    ``TabScene`` shows it by moving and scaling the pair under its fixed camera instead.

    Attributes:
        x: Centre of the view, metres.
        y: Centre of the view, metres.
        height: Camera height, metres.
        pixels_per_metre: Scale at z = 0 in the browser's view.
        lens: The (fov, aspect, pixel height) it was made for.
    """

    x: float
    y: float
    height: float
    pixels_per_metre: float
    lens: tuple[float, float, int]


def framing(
    view: EdgeView,
    placed: PlacedPair,
    lens: tuple[float, float, int],
    fill: float = FILL,
) -> Framing:
    """The lowest top-down camera that shows both scans (and both poses) within ``fill``.

    Only points inside the VGM's square count: that is what the validator sees, and the
    few returns of a long corridor tens of metres out would shrink the pair to nothing.

    Args:
        view: The edge drawn.
        placed: The placement drawn (estimate or guess).
        lens: Vertical field of view (radians), width over height of the 3D view (viser's
            canvas ends where the panel begins) and its height in pixels.
        fill: Largest share of the view's width or height the pair covers.
    """
    fov, aspect, pixels_high = lens
    points = np.concatenate([view.prev[:, :2], placed.cur[:, :2], [[0.0, 0.0], placed.pose[:2]]])
    inside = points[np.all(np.abs(points) <= view.extent / 2, axis=1)]
    lo, hi = inside.min(axis=0), inside.max(axis=0)
    half = (hi - lo) / 2
    tan = math.tan(fov / 2)
    height = max(half[1] / tan, half[0] / (tan * aspect), 0.0) / fill
    height = max(float(height), _MIN_HEIGHT)
    centre = (lo + hi) / 2
    ppm = pixels_high / (2 * height * tan)
    return Framing(float(centre[0]), float(centre[1]), height, ppm, lens)


class TabScene:
    """The nodes of one tab's scene, made on the first edge and updated after.

    The camera stays where it was put once, straight down from ``CAMERA_HEIGHT``; framing a
    pair moves and scales the pair's geometry into that view instead. Moving viser's camera
    costs the browser a camera round trip and extra frames, a third of a click's latency
    without a GPU; the points, image and pose marks are sent for every edge anyway.
    Updating a node's data is much cheaper than removing and adding it again.
    """

    def __init__(self, client: viser.ClientHandle) -> None:
        self.client = client
        self.nodes: dict[str, Any] = {}
        self.layers = Layers.both
        self.frame: Framing | None = None
        self._shown: tuple[EdgeView, PlacedPair] | None = None

    def show(self, view: EdgeView, placed: PlacedPair, reframe: bool = True) -> None:
        """Draws the pair; ``reframe`` fits it to the view anew (a new edge or placement)."""
        self._shown = (view, placed)
        if reframe or self.frame is None:
            self.frame = framing(view, placed, self._lens())
        self._draw()

    def _draw(self) -> None:
        assert self._shown is not None and self.frame is not None
        view, placed = self._shown
        f = self.frame
        centre, scale = np.array([f.x, f.y]), CAMERA_HEIGHT / f.height

        def fit(xyz: NDArray[np.float32]) -> NDArray[np.float32]:
            out = xyz.copy()
            out[..., :2] = (xyz[..., :2] - centre) * scale
            return out

        first = not self.nodes
        if first:
            self._make(view, placed)
            self.reset_view()
        cells = self.nodes["vgm"]
        cells.points, cells.colors = fit(placed.cells), self._cell_colours(placed)
        cell_size = placed.resolution * scale
        if not math.isclose(cells.point_size, cell_size, rel_tol=1e-3):
            cells.point_size = cell_size
        self.nodes["previous"].points = fit(view.prev)
        self.nodes["current"].points = fit(placed.cur)
        segments, colours = pose_marks(placed.pose, view.reference)
        self.nodes["poses"].points, self.nodes["poses"].colors = fit(segments), colours
        if view.reference is not None:
            self.nodes["reference_scan"].points = fit(view.reference[1])
        self._apply_layers(view.reference is not None)
        self._size_points()

    def lens_changed(self) -> None:
        """Fits the pair again when the browser's view changed shape (a resize, the panel).

        Called on every camera report; a pan or zoom by the annotator keeps the lens, so it
        is left alone.
        """
        if self.frame is None or self._shown is None:
            return
        fov, aspect, pixels = lens = self._lens()
        old_fov, old_aspect, old_pixels = self.frame.lens
        if (
            abs(aspect - old_aspect) > 0.01 * old_aspect
            or abs(fov - old_fov) > 1e-3
            or pixels != old_pixels
        ):
            self.frame = framing(*self._shown, lens)
            self._draw()

    def _size_points(self) -> None:
        if self.frame is None:
            return
        # In the fitted scene a metre of the pair is CAMERA_HEIGHT / height units.
        size = POINT_PIXELS[self.layers.value] / self.frame.pixels_per_metre
        size *= CAMERA_HEIGHT / self.frame.height
        for name in ("previous", "current", "reference_scan"):
            node = self.nodes[name]
            if not math.isclose(node.point_size, size, rel_tol=0.02):
                node.point_size = size

    def _make(self, view: EdgeView, placed: PlacedPair) -> None:
        scene = self.client.scene
        self.nodes["vgm"] = scene.add_point_cloud(
            "/vgm",
            placed.cells,
            placed.cell_rgb,
            point_size=placed.resolution,
            point_shape="square",
        )
        self.nodes["previous"] = scene.add_point_cloud(
            "/scans/previous", view.prev, PREV_RGB, point_size=POINT_SIZE
        )
        self.nodes["current"] = scene.add_point_cloud(
            "/scans/current", placed.cur, CUR_RGB, point_size=POINT_SIZE
        )
        self.nodes["reference_scan"] = scene.add_point_cloud(
            "/reference/scan", _ONE_POINT, REFERENCE_RGB, point_size=POINT_SIZE
        )
        segments, colours = pose_marks(placed.pose, view.reference)
        self.nodes["poses"] = scene.add_line_segments(
            "/poses", segments, colours, thickness=4.0, thickness_units="screen"
        )

    def _cell_colours(self, placed: PlacedPair) -> NDArray[np.uint8]:
        return placed.raw_rgb if self.layers is Layers.raw else placed.cell_rgb

    def _apply_layers(self, has_reference: bool) -> None:
        points = self.layers in (Layers.both, Layers.raw, Layers.points)
        wanted = {
            "vgm": self.layers in (Layers.both, Layers.raw, Layers.vgm),
            "previous": points,
            "current": points,
            "reference_scan": points and has_reference,
            "poses": True,
        }
        for name, visible in wanted.items():
            node = self.nodes.get(name)
            if node is not None and node.visible != visible:
                node.visible = visible

    def cycle_layers(self) -> Layers:
        """Steps to the next layers (V) and shows them on the pair drawn now."""
        before = self.layers
        self.layers = self.layers.next()
        if self._shown is not None:
            if Layers.raw in (before, self.layers) and "vgm" in self.nodes:
                self.nodes["vgm"].colors = self._cell_colours(self._shown[1])
            self._apply_layers(self._shown[0].reference is not None)
            self._size_points()
        return self.layers

    def clear(self) -> None:
        self._shown = None
        for node in self.nodes.values():
            if node.visible:
                node.visible = False

    def _lens(self) -> tuple[float, float, int]:
        """(vertical fov, aspect, pixel height) of the tab's 3D view, once the browser said."""
        fallback = (_FALLBACK_FOV, _FALLBACK_ASPECT, _FALLBACK_PIXELS)
        try:
            camera = self.client.camera
            fov, aspect, pixels = float(camera.fov), float(camera.aspect), camera.image_height
        except (AssertionError, AttributeError):
            return fallback
        if not (math.isfinite(fov) and math.isfinite(aspect) and fov > 0 and aspect > 0):
            return fallback
        return fov, aspect, int(pixels) if pixels else _FALLBACK_PIXELS

    def reset_view(self) -> None:
        """Puts the camera back straight above the fitted pair, +x right and +y up."""
        camera = self.client.camera
        camera.up_direction = (0.0, 0.0, 1.0)
        # A hair south of straight down: looking exactly along "up" leaves the view's roll
        # undefined; this keeps +y up on screen.
        camera.position = (0.0, -1e-4 * CAMERA_HEIGHT, CAMERA_HEIGHT)
        camera.look_at = (0.0, 0.0, 0.0)
