"""Bridging small gaps in a branch skeleton (beyond the paper, for real masks).

Hand labels and learned segmenters often leave a gap of a few pixels where a side branch meets
the trunk, or break a thin branch in two. Thinning then gives separate skeleton components: no
junction, so no secondary candidate (paper IV-B finds candidates only at junctions of the primary
path), or a primary cut short. :func:`find_bridges` proposes straight bridges from a skeleton
endpoint to the nearest skeleton pixel of another component when

* a ray from the endpoint crosses at most ``max_gap_px`` of background between the two
  silhouettes,
* the branch ending there points at the other component (its outward tangent within
  ``max_angle_deg`` of the bridge), and
* the endpoint's component is long enough to be a branch (``min_length_px`` and four radii),
  and its terminal edge holds a straight run to take the tangent on: a lone blob beside the
  trunk, or speckle, has almost no skeleton and is never bridged.

A thin occluder in front of a branch (a trellis wire, a tie, a twig crossing the view) cuts its
mask into pieces with wider gaps, and the pieces between two wires may be short. An *occlusion
bridge* spans such a gap when the branch continues across it unchanged (:class:`OcclusionRule`):

* the gap is at most ``gap_radii`` times the branch's radius (an occluder up to about a branch
  diameter wide),
* the ray leaves the endpoint within ``max_angle_deg`` of its outward tangent,
* the piece on the far side has the same width across the mask (ratio at most
  ``width_ratio``) and is centred on the near piece's axis (off it by at most ``max_angle_deg``
  as seen from the near piece), and
* the endpoint's piece is at least ``min_elongation`` radii long.

It is tried only at endpoints where the small-gap rule above finds nothing.

Bridges are taken shortest gap first, at most one per pair of components (no loops).
``recon/curve2d/skeleton.py`` draws them into the skeleton before building the graph; the
bridge pixels lie off the mask, and samples there are not lifted (``recon/curve2d/fit.py``).

All pixel coordinates are ``(u, v)`` = (column, row), as in ``recon.camera``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from recon.curve2d.path_search import component_reach
from recon.curve2d.skeleton_graph import SkeletonEdge, SkeletonGraph

__all__ = ["Bridge", "OcclusionRule", "find_bridges"]

_RAYS = 7  # rays fanned over the allowed angle (ours: ~10 deg apart for the default 30 deg)
_RAY_STEP_PX = 0.5  # ray marching step: below a pixel, no pixel skipped
_RAY_MARGIN_PX = 2.0  # rounding slack at both silhouette edges
# An occlusion bridge's direction is the chord over up to this many tangent lengths of the
# terminal edge (ours: past a cut end's corner, still the branch's own direction).
_OCCLUSION_CHORD_TANGENTS = 4.0
# Thinning bends a skeleton within ~1.5 radii of a cut end (its hook into a corner of the cut;
# corner spurs are ~sqrt(2) radii long). Also ``recon/curve2d/skeleton.py``'s border extension.
END_ARTEFACT_RADII = 1.5
# A wide piece's skeleton narrows into a thin branch where its radius falls below 1/2 of the
# wide end's (ours: twice the occlusion rule's default width ratio of one branch, 1.5, would
# be 3; a side branch is 0.3-0.5x its trunk's radius, reference.md and docs/worlds.md).
_WIDTH_DROP = 2.0
# A bridged component's skeleton is at least this many radii long (ours: two diameters; a blob's
# skeleton is shorter than its diameter).
_MIN_ELONGATION = 4.0


@dataclass(frozen=True)
class OcclusionRule:
    """When a wider gap is an occluder in front of one branch (module docstring).

    Attributes:
        gap_radii: Largest gap, in radii of the branch at the endpoint; 0 disables.
        max_angle_deg: Largest angle between the near piece's axis and the bridge, and between
            that axis and the far piece's centre seen from the near piece.
        width_ratio: Largest ratio between the two pieces' widths (either way).
        min_elongation: Shortest skeleton of the endpoint's piece, in its radii.
        wide_ends: Also measure a cut end past the thinning's end hook, and take the point
            where a wide piece's skeleton narrows into a thin branch as a cut end (see
            :func:`_occlusion_target`); False: only the skeleton's tip, as before.
    """

    gap_radii: float = 0.0
    max_angle_deg: float = 15.0
    width_ratio: float = 1.5
    min_elongation: float = 2.0
    wide_ends: bool = True


class _Targets(NamedTuple):
    """What an occlusion bridge may reach (:func:`find_bridges`' tables).

    Attributes:
        labels: (H, W) int mask component of every pixel (0: background).
        pixels: (P, 2) int every skeleton pixel (u, v).
        pixel_label: (P,) the mask component of each.
        other_component: (P,) True for the pixels of other skeleton components than the
            endpoint's.
        targetable: () -> (P,) True for the pixels outside the skeleton's end zones.
        angles: (R,) ray angles (rad) about a piece's axis.
        max_gap_px: The small-gap rule's largest gap (an occlusion bridge's is wider).
        tangent_px: Arc length over which a tangent is measured.
    """

    labels: np.ndarray
    pixels: np.ndarray
    pixel_label: np.ndarray
    other_component: np.ndarray
    targetable: Callable[[], np.ndarray]
    angles: np.ndarray
    max_gap_px: float
    tangent_px: float


@dataclass(frozen=True)
class Bridge:
    """A straight bridge over a gap.

    Attributes:
        start_uv: (2,) int skeleton pixel (u, v) the bridge leaves from: one radius back from
            an endpoint, past the thinning's end hook.
        end_uv: (2,) int skeleton pixel (u, v) of the other component it reaches.
        radius_px: Radius given to the bridge pixels (the endpoint's).
        gap_px: Estimated gap between the two silhouettes, in pixels.
        erase_uv: (K, 2) int skeleton pixels (u, v) to remove: the end hooks of a wide piece
            bridged past them (``OcclusionRule.wide_ends``), which would otherwise stay as
            spurs into the corners of the cut and be lifted as side branches (measured: two
            spurious branches on a synthetic leader cut by a crossing branch).
    """

    start_uv: np.ndarray
    end_uv: np.ndarray
    radius_px: float
    gap_px: float
    erase_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))


def find_bridges(
    graph: SkeletonGraph,
    mask: np.ndarray,
    interior_uv: tuple[int, int, int, int],
    max_gap_px: float,
    max_angle_deg: float,
    min_length_px: float,
    tangent_px: float,
    occlusion: OcclusionRule | None = None,
) -> list[Bridge]:
    """Bridges over small gaps between skeleton components (see the module docstring).

    The gap is measured in the mask: rays from a skeleton endpoint, within ``max_angle_deg`` of
    its outward tangent, leave the branch's own silhouette, cross the background and must enter
    another mask component within ``max_gap_px``; the bridge goes to the other component's
    skeleton pixel nearest to where the shortest-gap ray enters it.

    Args:
        graph: The skeleton graph.
        mask: (H, W) bool clean mask the skeleton came from.
        interior_uv: (u_min, v_min, u_max, v_max) of the interior: endpoints on its outline are
            branches leaving the view, never bridged.
        max_gap_px: Largest gap between silhouettes to bridge; 0 disables bridging.
        max_angle_deg: Largest angle between an endpoint's outward tangent and its bridge.
        min_length_px: Shortest skeleton (polyline length of its component) that may be bridged.
        tangent_px: Arc length over which the outward tangent at an endpoint is measured.
        occlusion: When a wider gap is bridged as an occluder in front of one branch (None:
            never).

    Returns:
        The bridges to draw, shortest gap first.
    """
    occlusion = occlusion or OcclusionRule()
    if (max_gap_px <= 0 and occlusion.gap_radii <= 0) or len(graph.edges) < 2:
        return []
    component, _ = component_reach(graph)
    edge_component = component[[e.start for e in graph.edges]]
    if len(np.unique(edge_component)) < 2:
        return []
    lengths = np.zeros(graph.n_nodes)
    np.add.at(lengths, edge_component, [e.length_px for e in graph.edges])
    n_labels, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    if n_labels < 3:  # background and one silhouette: nothing to bridge
        return []
    pixels = np.concatenate([e.pixels_uv for e in graph.edges])
    owner = np.repeat(edge_component, [len(e.pixels_uv) for e in graph.edges])
    pixel_label = labels[pixels[:, 1], pixels[:, 0]]
    # Never bridge into the last radius of a skeleton end: thinning hooks it into a corner of a
    # cut end; the bridge goes past the hook, which is then pruned as a spur.
    # Computed once, when a ray first reaches another component (most frames bridge nothing).
    targetable = functools.cache(
        lambda: ~np.concatenate([_end_zone(graph, e) for e in graph.edges])
    )
    u_min, v_min, u_max, v_max = interior_uv
    pixel_edge = np.repeat(np.arange(len(graph.edges)), [len(e.pixels_uv) for e in graph.edges])
    edge_first = np.concatenate([[0], np.cumsum([len(e.pixels_uv) for e in graph.edges])[:-1]])

    def far_hook(target: int) -> np.ndarray:
        """The far piece's end hook beyond a bridge's target: the part of the target's edge
        from it to an endpoint inside the interior at most ``END_ARTEFACT_RADII + 1`` radii
        (the target's) of skeleton away (a corner of the cut; a side branch is longer)."""
        edge = graph.edges[pixel_edge[target]]
        at = target - edge_first[pixel_edge[target]]
        radius_px = float(edge.radii_px[at])
        for node, hook in ((edge.start, edge.pixels_uv[:at]), (edge.end, edge.pixels_uv[at + 1 :])):
            tip = graph.node_uv[node]
            if (
                graph.node_kind[node] == "endpoint"
                and len(graph.incident_edges(node)) == 1
                and u_min < tip[0] < u_max
                and v_min < tip[1] < v_max
                and len(hook) > 1
                and np.linalg.norm(np.diff(hook, axis=0), axis=1).sum()
                <= (END_ARTEFACT_RADII + 1.0) * radius_px
            ):
                return hook
        return edge.pixels_uv[:0]

    angles = np.radians(np.linspace(-max_angle_deg, max_angle_deg, _RAYS))
    occlusion_angles = np.radians(
        np.linspace(-occlusion.max_angle_deg, occlusion.max_angle_deg, _RAYS)
    )
    proposals: list[tuple[float, int, int, Bridge]] = []
    for edge in graph.edges:
        for node, path, path_radii in (
            (edge.start, edge.pixels_uv, edge.radii_px),
            (edge.end, edge.pixels_uv[::-1], edge.radii_px[::-1]),
        ):
            if graph.node_kind[node] != "endpoint" or len(graph.incident_edges(node)) != 1:
                continue
            own = component[node]
            end = path[0]
            if lengths[own] < min_length_px:
                continue
            if end[0] <= u_min or end[0] >= u_max or end[1] <= v_min or end[1] >= v_max:
                continue
            own_label = labels[end[1], end[0]]
            radius = float(np.median(path_radii[: max(2, int(tangent_px))]))
            if edge.length_px < radius + tangent_px:
                continue  # no straight run to take a tangent on
            outward = _outward_tangent(path.astype(float), radius, tangent_px)
            if outward is None:
                continue
            found = None
            if max_gap_px > 0 and lengths[own] >= _MIN_ELONGATION * radius:  # else blob-like
                found = _bridge_target(
                    labels, end, outward, angles, own_label, radius, max_gap_px,
                    pixels, pixel_label, owner != own, targetable,
                )  # fmt: skip
            start, hook = _pixel_at_arc(path, radius), path[:0]
            if found is None and occlusion.gap_radii > 0:
                found, start, hook = _occlusion_target(
                    path, edge.length_px, path_radii, own_label, lengths[own],
                    _Targets(labels, pixels, pixel_label, owner != own, targetable,
                             occlusion_angles, max_gap_px, tangent_px),
                    occlusion,
                )  # fmt: skip
            if found is None:
                continue
            gap, target = found
            if len(hook):  # bridged past its hook: the far piece's goes too
                hook = np.concatenate([hook, far_hook(target)])
            bridge = Bridge(start.astype(int), pixels[target].astype(int), radius, gap, hook)
            proposals.append((gap, int(own), int(owner[target]), bridge))
        if occlusion.gap_radii <= 0 or not occlusion.wide_ends:
            continue
        for node, path, path_radii in (
            (edge.start, edge.pixels_uv, edge.radii_px),
            (edge.end, edge.pixels_uv[::-1], edge.radii_px[::-1]),
        ):
            # A wide piece whose skeleton runs on into a thin branch at its cut end (a side
            # branch flush with the occluder's edge): its end is where the width drops.
            if graph.node_kind[node] != "endpoint" or len(graph.incident_edges(node)) != 1:
                continue
            drop = _width_drop(path_radii, tangent_px)
            if drop is None:
                continue
            wide, wide_radii = path[drop::-1], path_radii[drop::-1]
            end, own = wide[0], component[node]
            if end[0] <= u_min or end[0] >= u_max or end[1] <= v_min or end[1] >= v_max:
                continue
            wide_length = float(np.linalg.norm(np.diff(wide.astype(float), axis=0), axis=1).sum())
            radius = float(np.median(wide_radii))
            skip_px = END_ARTEFACT_RADII * radius  # past the bend into the thin branch
            if wide_length - skip_px < tangent_px:
                continue
            found = _occlusion_hit(
                wide, wide_length, skip_px, labels[end[1], end[0]], lengths[own],
                _Targets(labels, pixels, pixel_label, owner != own, targetable,
                         occlusion_angles, max_gap_px, tangent_px),
                occlusion,
            )  # fmt: skip
            if found is not None:
                gap, target = found
                start = _pixel_at_arc(wide, skip_px)
                hook = far_hook(target)
                bridge = Bridge(start.astype(int), pixels[target].astype(int), radius, gap, hook)
                proposals.append((gap, int(own), int(owner[target]), bridge))
    proposals.sort(key=lambda p: (p[0], p[1], p[2]))
    parent = {int(c): int(c) for c in np.unique(component)}

    def root(c: int) -> int:
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    bridges = []
    for _, a, b, bridge in proposals:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
            bridges.append(bridge)
    return bridges


def _bridge_target(
    labels: np.ndarray,
    end: np.ndarray,
    outward: np.ndarray,
    angles: np.ndarray,
    own_label: int,
    radius_px: float,
    max_gap_px: float,
    pixels: np.ndarray,
    pixel_label: np.ndarray,
    other_component: np.ndarray,
    targetable: Callable[[], np.ndarray],
) -> tuple[float, int] | None:
    """(gap, index of the skeleton pixel bridged to) across the shortest gap within
    ``max_gap_px`` from the endpoint ``end``, if any: the other component's targetable skeleton
    pixel nearest to where the ray enters its silhouette."""
    hit = _shortest_gap_ray(labels, end, outward, angles, own_label, radius_px, max_gap_px)
    if hit is None:
        return None
    gap, entry, label = hit
    return _nearest_target(gap, entry, label, pixels, pixel_label, other_component, targetable)


def _nearest_target(
    gap: float,
    entry: np.ndarray,
    label: int,
    pixels: np.ndarray,
    pixel_label: np.ndarray,
    other_component: np.ndarray,
    targetable: Callable[[], np.ndarray],
) -> tuple[float, int] | None:
    """(gap, index of the other component's targetable skeleton pixel on mask component
    ``label`` nearest to ``entry``), or None when it has none. ``targetable()`` gives the (P,)
    skeleton pixels that may be bridged to (outside the end zones)."""
    on_label = np.flatnonzero((pixel_label == label) & other_component & targetable())
    if len(on_label) == 0:
        return None
    return gap, int(on_label[np.argmin(np.linalg.norm(pixels[on_label] - entry, axis=1))])


def _occlusion_target(
    path: np.ndarray,
    edge_length_px: float,
    edge_radii_px: np.ndarray,
    own_label: int,
    own_length_px: float,
    targets: _Targets,
    rule: OcclusionRule,
) -> tuple[tuple[float, int] | None, np.ndarray, np.ndarray]:
    """:func:`_bridge_target` for an occlusion bridge (:class:`OcclusionRule`), the skeleton
    pixel the bridge leaves from, and the end hook it leaves behind (to erase; empty when the
    bridge leaves from the tip).

    Args:
        path: (P, 2) the terminal edge's skeleton pixels, from the endpoint.
        edge_length_px: Its polyline length.
        edge_radii_px: (P,) its pixels' radii.

    Returns:
        ((gap, index of the skeleton pixel bridged to) or None, (2,) start pixel (u, v),
        (K, 2) hook pixels (u, v)).

    Directions and widths are taken over the branch's end, not at the skeleton's tip: a wide
    branch's skeleton bends into a corner of a cut end, so the outward direction is the chord
    over the terminal edge (up to ``_OCCLUSION_CHORD_TANGENTS`` tangent lengths) and widths are
    measured across the mask, ``tangent_px`` back from the tip. Where that finds nothing, the
    end is measured again past the thinning's end hook (:data:`END_ARTEFACT_RADII` radii of
    the edge's far half): a wide trunk cut at a slant by an occluder (a crossing branch in front
    of it) has a hook as long as its radius that turns the chord 30 deg or more off the trunk
    (measured, orchard seed 7000: a 27 px radius leader cut by a 12 px band, its two ends'
    chords 33 deg off vertical, and the scan lost). That try takes its direction, width and
    rays from the trunk's axis behind the hook, bridges from the skeleton there, and to the far
    piece's skeleton past its own hook, so that the bridge runs along the axis across the gap.
    """
    found = _occlusion_hit(path, edge_length_px, 0.0, own_label, own_length_px, targets, rule)
    tangent_px = targets.tangent_px
    start = _pixel_at_arc(path, float(np.median(edge_radii_px[: max(2, int(tangent_px))])))
    if found is not None or not rule.wide_ends:
        return found, start, path[:0]
    # The branch's radius over the half of the edge away from the tip (the hook narrows).
    skip_px = END_ARTEFACT_RADII * float(np.median(edge_radii_px[len(edge_radii_px) // 2 :]))
    if edge_length_px - skip_px < tangent_px:
        return None, start, path[:0]  # no straight run behind the hook
    found = _occlusion_hit(path, edge_length_px, skip_px, own_label, own_length_px, targets, rule)
    steps = np.linalg.norm(np.diff(path.astype(float), axis=0), axis=1)
    at = min(
        int(np.searchsorted(np.concatenate([[0.0], np.cumsum(steps)]), skip_px)), len(path) - 1
    )
    return found, path[at], path[:at]  # the hook: from the tip to the bridge's start


def _occlusion_hit(
    path: np.ndarray,
    edge_length_px: float,
    skip_px: float,
    own_label: int,
    own_length_px: float,
    targets: _Targets,
    rule: OcclusionRule,
) -> tuple[float, int] | None:
    """One try of :func:`_occlusion_target`, the branch's end measured ``skip_px`` of skeleton
    back from the tip: (gap, index of the skeleton pixel bridged to), or None.

    With ``skip_px`` 0 the rays leave from the skeleton's tip and the target is the far
    piece's skeleton pixel nearest to where the shortest ray enters it; otherwise the rays leave
    from the axis there (the tip sits in a corner of the cut) and the target is the far piece's
    skeleton pixel nearest to its axis :data:`END_ARTEFACT_RADII` radii past the gap.
    """
    tangent_px, angles = targets.tangent_px, targets.angles
    chord = min(edge_length_px - skip_px, _OCCLUSION_CHORD_TANGENTS * tangent_px)
    outward = _outward_tangent(path.astype(float), skip_px, chord)
    if outward is None:
        return None
    arc = skip_px + min(tangent_px, 0.5 * (edge_length_px - skip_px))
    back = _pixel_at_arc(path, arc).astype(float)
    labels = targets.labels
    half_width, offset = _cross_section(labels, own_label, back, outward)
    normal = np.array([-outward[1], outward[0]])
    centre = back + offset * normal  # on the branch's axis
    gap_limit = rule.gap_radii * half_width
    if gap_limit <= targets.max_gap_px or own_length_px < rule.min_elongation * half_width:
        return None
    if skip_px > 0.0:  # from the axis: through the rest of the piece (its slanted cut end too)
        hit = _shortest_gap_ray(
            labels, centre, outward, angles, own_label, half_width, gap_limit,
            lead_px=arc + 2.0 * half_width,
        )  # fmt: skip
    else:
        hit = _shortest_gap_ray(labels, path[0], outward, angles, own_label, half_width, gap_limit)
    if hit is None:
        return None
    gap, entry, label = hit
    # The far piece, one radius past the gap on the branch's axis: as wide and centred on it.
    along = float((entry - centre) @ outward) + half_width
    far_half_width, far_offset = _cross_section(labels, label, centre + along * outward, outward)
    if not (
        far_half_width > 0
        and max(far_half_width, half_width) <= rule.width_ratio * min(far_half_width, half_width)
        and abs(far_offset) <= along * np.tan(np.radians(rule.max_angle_deg)) + _RAY_MARGIN_PX
    ):
        return None  # another width, or off to one side: not the same branch going on
    if skip_px > 0.0:  # on the far piece's axis, past its end hook
        past = along - half_width + END_ARTEFACT_RADII * far_half_width
        on_axis = _first_on_axis(
            centre + far_offset * normal, outward, past, label, targets.pixels,
            targets.pixel_label, targets.other_component,  # past the hook: no end zones
        )  # fmt: skip
        if on_axis is not None:
            return gap, on_axis
        entry = centre + past * outward + far_offset * normal
    return _nearest_target(gap, entry, label, *targets[1:5])


def _first_on_axis(
    axis_point: np.ndarray,
    axis: np.ndarray,
    from_px: float,
    label: int,
    pixels: np.ndarray,
    pixel_label: np.ndarray,
    allowed: np.ndarray,
) -> int | None:
    """Index of the first skeleton pixel of mask component ``label`` (among the ``allowed``)
    on the axis line through ``axis_point`` along unit ``axis``, beyond ``from_px`` along it
    (within ``_RAY_MARGIN_PX`` of the line), or None."""
    offset = pixels - axis_point
    along = offset @ axis
    across = np.abs(offset @ np.array([-axis[1], axis[0]]))
    candidates = np.flatnonzero(
        (pixel_label == label) & allowed & (across <= _RAY_MARGIN_PX) & (along >= from_px)
    )
    if len(candidates) == 0:
        return None
    return int(candidates[np.argmin(along[candidates])])


def _cross_section(
    labels: np.ndarray, label: int, point: np.ndarray, direction: np.ndarray
) -> tuple[float, float]:
    """(half width, centre offset) in pixels of mask component ``label`` across ``direction``
    at ``point``: the run of its pixels through ``point`` perpendicular to ``direction``; the
    offset is the run's centre from ``point``, positive to the left of ``direction``. (0, 0)
    when ``point`` is not on the component."""
    h, w = labels.shape
    normal = np.array([-direction[1], direction[0]])
    steps = np.arange(0.0, float(max(h, w)), _RAY_STEP_PX)
    extents = []
    for sign in (1.0, -1.0):
        uv = np.rint(point[None, :] + sign * steps[:, None] * normal[None, :]).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        on = inside & (labels[np.clip(uv[:, 1], 0, h - 1), np.clip(uv[:, 0], 0, w - 1)] == label)
        off = np.flatnonzero(~on)
        if len(off) and off[0] == 0:
            return 0.0, 0.0
        extents.append(float(steps[off[0]]) if len(off) else float(steps[-1]))
    left, right = extents
    return 0.5 * (left + right), 0.5 * (left - right)


def _shortest_gap_ray(
    labels: np.ndarray,
    start: np.ndarray,
    outward: np.ndarray,
    angles: np.ndarray,
    own_label: int,
    radius_px: float,
    max_gap_px: float,
    lead_px: float | None = None,
) -> tuple[float, np.ndarray, int] | None:
    """March rays from ``start`` at ``angles`` about ``outward``: (gap, entry pixel, label) of
    the ray that enters another mask component after the shortest run of background, if any
    run is at most ``max_gap_px`` long. ``lead_px``: the longest run inside its own silhouette
    before the gap (default two radii: a skeleton may end well inside a cut end)."""
    h, w = labels.shape
    lead = 2.0 * radius_px if lead_px is None else lead_px
    reach = lead + max_gap_px + _RAY_MARGIN_PX  # out of its own silhouette, across, into another
    steps = np.arange(0.0, reach, _RAY_STEP_PX)
    cos, sin = np.cos(angles), np.sin(angles)
    dirs = np.stack([cos * outward[0] - sin * outward[1], sin * outward[0] + cos * outward[1]], 1)
    pts = start[None, None, :] + steps[None, :, None] * dirs[:, None, :]  # (R, S, 2)
    uv = np.rint(pts).astype(int)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < w) & (uv[..., 1] >= 0) & (uv[..., 1] < h)
    lab = np.where(inside, labels[np.clip(uv[..., 1], 0, h - 1), np.clip(uv[..., 0], 0, w - 1)], 0)
    best = None
    for r in range(len(angles)):
        ray = lab[r]
        out = np.flatnonzero(ray != own_label)
        if len(out) == 0:
            continue
        first_out = out[0]
        other = np.flatnonzero((ray[first_out:] != 0) & (ray[first_out:] != own_label))
        if len(other) == 0:
            continue
        k = first_out + other[0]
        if np.any(ray[first_out:k] == own_label):  # re-entered itself: not a straight gap
            continue
        gap = float(steps[k] - steps[first_out])
        if gap <= max_gap_px and (best is None or gap < best[0]):
            best = (gap, pts[r, k], int(ray[k]))
    return best


def _width_drop(radii: np.ndarray, tangent_px: float) -> int | None:
    """Where a skeleton path that starts wide narrows into a thin branch, or None.

    Args:
        radii: (P,) radii along the path, from its wide end.
        tangent_px: The stretch (in pixels of path) over which the wide end's radius and the
            thin branch's are measured.

    Returns:
        The index of the first pixel narrower than ``1 / _WIDTH_DROP`` of the wide end's radius
        (median of its first ``tangent_px`` pixels), when the path behind it holds a straight run
        (:data:`END_ARTEFACT_RADII` radii and ``tangent_px``) and the path beyond it, at least
        ``tangent_px`` and longer than a hook into a corner of a cut (``END_ARTEFACT_RADII + 1``
        wide radii), stays that thin (median); else None.
    """
    n = max(2, int(tangent_px))
    if len(radii) < 2 * n:
        return None
    wide = float(np.median(radii[:n]))
    narrow = np.flatnonzero(radii < wide / _WIDTH_DROP)
    if len(narrow) == 0 or narrow[0] < END_ARTEFACT_RADII * wide + tangent_px:
        return None
    thin = radii[narrow[0] :]
    # Longer than a hook into a corner of the cut (which the endpoint's own try bridges past).
    if len(thin) < max(n, (END_ARTEFACT_RADII + 1.0) * wide) or float(np.median(thin)) >= (
        wide / _WIDTH_DROP
    ):
        return None
    return int(narrow[0])


def _end_zone(graph: SkeletonGraph, edge: SkeletonEdge) -> np.ndarray:
    """(P,) True for an edge's pixels within one end radius of a skeleton endpoint."""
    zone = np.zeros(len(edge.pixels_uv), dtype=bool)
    steps = np.linalg.norm(np.diff(edge.pixels_uv.astype(float), axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    if graph.node_kind[edge.start] == "endpoint":
        zone |= arc <= edge.radii_px[0] + float(np.median(edge.radii_px))
    if graph.node_kind[edge.end] == "endpoint":
        zone |= arc[-1] - arc <= edge.radii_px[-1] + float(np.median(edge.radii_px))
    return zone


def _pixel_at_arc(path: np.ndarray, arc_px: float) -> np.ndarray:
    """The pixel of ``path`` about ``arc_px`` of polyline length from ``path[0]``."""
    steps = np.linalg.norm(np.diff(path.astype(float), axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    return path[min(int(np.searchsorted(arc, arc_px)), len(path) - 1)]


def _outward_tangent(path: np.ndarray, skip_px: float, tangent_px: float) -> np.ndarray | None:
    """Unit direction out of the skeleton at ``path[0]``, measured between the pixels
    ``skip_px`` and ``skip_px + tangent_px`` back (past the thinning's end hooks)."""
    direction = _pixel_at_arc(path, skip_px) - _pixel_at_arc(path, skip_px + tangent_px)
    norm = float(np.linalg.norm(direction))
    return direction / norm if norm > 0 else None
