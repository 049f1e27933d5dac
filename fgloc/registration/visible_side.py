"""Where the radar sees a vehicle, measured on the tracks: the visible-side offset per aspect.

A radar sees a vehicle's sensor-facing faces, so its detections lie towards the sensor from
the vehicle's centre line. How far depends on the aspect: seen head-on (line of sight along
the heading) they spread over the front or rear face, about a third of a metre off the
centre line on simulated traffic; seen broadside they lie on the near side, half a width
(0.8-1.1 m) off. A constant ``coarse.visible_side_offset`` cannot hold both, and where the
pose along a street is fixed by a few lanes seen at one aspect (a junction with one main
street and few turns) the difference moves the pose (docs/experiments.md, issue 22).

:func:`measure_visible_side` measures the offset on the tracks themselves: every detection a
track used, relative to its track's centre at that step, across the track's heading towards
the sensor, binned by the aspect ``s = |sin|`` of the angle between the line of sight (sensor
to the track's centre) and the heading. Offsets relative to a track's own centre do not
depend on where the frame C is, so a coarse pose that is off does not bias them. The fine
stage then shifts each lane sample by the offset at its own aspect seen from the sensor
(:meth:`VisibleSide.at`). The offsets are means over detections, so the source cloud's voxels
are weighted by how many detections they average (:class:`fgloc.registration.source.SourceCloud`
``weight``): an unweighted voxel centroid counts sparse far-side returns as much as the dense
near side and sits nearer the centre line than the detections do on average.

A detection on a front or rear face also lies up to half a length ahead of or behind its
vehicle's centre, off the lane where the lane curves (on a turn of 10-15 m radius a point
2.25 m ahead on the tangent lies 0.2 m outside the arc), and the lane samples stand for where
the vehicles' centres drive. :func:`onto_cross_section` therefore moves each detection along
its track's heading onto the cross-section through the tracked centre before the voxels
average them: what stays is its place across the heading, which the offsets are about
(with the detections where they are, a simulated T-junction ended 0.4-0.6 m off; with each
detection's own true offset taken off but the along-heading part kept, still 0.54 m,
docs/experiments.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.tracks import YAW, Track

#: Edges of the aspect bins (|sin| of the angle between line of sight and heading).
ASPECT_EDGES: np.ndarray = np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
#: A bin with fewer detections than this takes its offset from its neighbours.
MIN_DETECTIONS: int = 20


@dataclass
class VisibleSide:
    """Mean offset (m) of the detections towards the sensor from their track's centre line
    per aspect bin (``ASPECT_EDGES``). offset: (B,) m, NaN where a bin had fewer than
    ``MIN_DETECTIONS``; count: (B,) detections per bin; fallback: m, the offset used when no
    bin has enough (``coarse.visible_side_offset``)."""

    offset: np.ndarray
    count: np.ndarray
    fallback: float

    def at(self, aspect: np.ndarray) -> np.ndarray:
        """Offsets (m) at aspects ``aspect`` (n,) (|sin|, 0..1): linear between the bin
        centres of the measured bins, constant beyond the outer ones; the fallback without
        any."""
        aspect = np.asarray(aspect, dtype=float)
        ok = np.isfinite(self.offset)
        if not ok.any():
            return np.full(aspect.shape, self.fallback)
        centres = 0.5 * (ASPECT_EDGES[:-1] + ASPECT_EDGES[1:])
        return np.interp(aspect, centres[ok], self.offset[ok])

    def summary(self) -> dict[str, object]:
        """JSON-ready bins, offsets (m, None for an empty bin) and detection counts."""
        return {"aspect_edges": ASPECT_EDGES.tolist(),
                "offset": [None if not np.isfinite(o) else float(o) for o in self.offset],
                "detections": self.count.astype(int).tolist()}


def aspect_and_offset(xy: np.ndarray, centre: np.ndarray, yaw: np.ndarray,
                      sensor_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Aspect ``|sin|`` (n,) of each vehicle state (centres (n, 2) m and headings (n,) rad,
    seen from ``sensor_xy`` (2,)) and the offset (n,) m of the points ``xy`` (n, 2) from its
    centre across the heading, positive towards the sensor. All in one frame."""
    normal = np.column_stack([-np.sin(yaw), np.cos(yaw)])
    los = centre - np.asarray(sensor_xy, dtype=float)
    dist = np.maximum(np.linalg.norm(los, axis=1), 1e-9)
    across = np.einsum("ij,ij->i", los, normal)
    towards = -np.sign(across)
    return np.abs(across) / dist, towards * np.einsum("ij,ij->i", xy - centre, normal)


def onto_cross_section(xy: np.ndarray, centre: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """The points ``xy`` (n, 2) moved along their vehicles' headings ``yaw`` (n,) rad onto the
    cross-sections through the vehicles' centres ``centre`` (n, 2): each keeps its place
    across its heading (module docstring). All in one frame, m."""
    heading = np.column_stack([np.cos(yaw), np.sin(yaw)])
    along = np.einsum("ij,ij->i", xy - centre, heading)
    return xy - along[:, None] * heading


def measure_visible_side(tracks: list[Track], detections_xy: np.ndarray, sensor_xy: np.ndarray,
                         fallback: float, bound: float = np.inf) -> VisibleSide:
    """The visible-side offsets of ``tracks`` (module docstring). detections_xy: (N, 2) m, the
    scenario's detections placed in the tracks' frame (indexed by ``det_index``); sensor_xy:
    (2,) m, the sensor in that frame; fallback: m, the offset without measurements.

    Each bin's mean is clipped to ``[0, bound]`` (m; the caller passes half the mean vehicle
    width): a detection lies on its vehicle, so the mean offset from the vehicle's centre line
    is 0 seen head-on (the faces seen are symmetric about it) and at most half a width seen
    broadside. A mean beyond that is the tracked centre's own bias, which the offsets relative
    to it carry (the filter's centre lies away from the sensor where it overestimates a
    broadside vehicle's width: 1.19-1.24 m at aspects 0.6-1 on junction 2 of the real map,
    docs/experiments.md, issue 22)."""
    parts = [aspect_and_offset(detections_xy[tr.det_index], tr.states[tr.det_step, :2],
                               tr.states[tr.det_step, YAW], sensor_xy) for tr in tracks]
    aspect = np.concatenate([p[0] for p in parts] + [np.zeros(0)])
    offset = np.concatenate([p[1] for p in parts] + [np.zeros(0)])
    nbin = len(ASPECT_EDGES) - 1
    b = np.clip(np.searchsorted(ASPECT_EDGES, aspect, side="right") - 1, 0, nbin - 1)
    count = np.bincount(b, minlength=nbin).astype(float)
    total = np.bincount(b, weights=offset, minlength=nbin)
    mean = np.where(count >= MIN_DETECTIONS, total / np.maximum(count, 1.0), np.nan)
    return VisibleSide(np.clip(mean, 0.0, bound), count, fallback)
