"""The in-memory scenario: typed containers for everything in a scenario directory.

Every array is float64 in the local ENU frame ``L`` of :attr:`Scenario.frame` (world minus a
rounded origin), except radar detections, which stay in the sensor frame ``S``, and the ALS
coordinates, which are float32 in ``L`` (millimetre resolution over several kilometres).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgloc.geo import LocalFrame

#: ASPRS LAS classification codes used by fgloc.
ASPRS_CLASSES: dict[int, str] = {
    0: "never classified",
    1: "unclassified",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low point (noise)",
    9: "water",
    11: "road surface",
    17: "bridge deck",
    20: "ignored ground",
}
#: ASPRS classes of the bare ground: 2 ground, 11 road surface.
GROUND_CLASSES: tuple[int, ...] = (2, 11)
#: ASPRS class of building points (the sight lines' obstacles; the simulator writes it).
BUILDING_CLASS: int = 6


@dataclass
class RadarData:
    """Radar detections in the sensor frame S.

    t: (N,) s, non-decreasing. xyz: (N, 3) m in S. doppler: (N,) m/s range rate, positive away
    from the sensor. rcs: (N,) dBsm or None. frame: (N,) int64 frame index or None (derived
    from equal t when absent).
    """

    t: np.ndarray
    xyz: np.ndarray
    doppler: np.ndarray
    rcs: np.ndarray | None = None
    frame: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0

    def frame_ids(self) -> np.ndarray:
        """(N,) int64 frame index per detection.

        The ``frame`` column when present; else detections sharing a timestamp form a frame;
        else (every detection stamped on its own) :func:`burst_frame_ids` groups them.
        """
        if self.frame is not None:
            return self.frame
        if len(self) == 0:
            return np.zeros(0, dtype=np.int64)
        ids = np.concatenate([[0], np.cumsum(np.diff(self.t) > 0)]).astype(np.int64)
        if len(self) >= 2 * (ids[-1] + 1):  # at least two detections per timestamp on average
            return ids
        return burst_frame_ids(self.t)


#: Longest plausible radar frame (s); longer bursts are cut into windows of this length / 4.
MAX_FRAME_SPAN = 0.2


def burst_frame_ids(t: np.ndarray, min_gap: float = 0.005) -> np.ndarray:
    """Frame ids for detections stamped one by one (t non-decreasing, s).

    A new frame starts at a gap in t longer than 10x the median positive step (and at least
    ``min_gap`` s). If that leaves frames longer than :data:`MAX_FRAME_SPAN` (continuous
    stamping without gaps), fixed windows of ``MAX_FRAME_SPAN / 4`` s (50 ms, a 20 Hz radar) are
    used instead.
    """
    dt = np.diff(t)
    pos = dt[dt > 0]
    thr = max(10.0 * float(np.median(pos)), min_gap) if len(pos) else np.inf
    ids = np.concatenate([[0], np.cumsum(dt > thr)]).astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], np.diff(ids) > 0]))
    ends = np.append(starts[1:], len(t)) - 1
    if np.max(t[ends] - t[starts]) <= MAX_FRAME_SPAN:
        return ids
    window = MAX_FRAME_SPAN / 4.0
    return np.floor((t - t[0]) / window).astype(np.int64)


@dataclass
class AlsCloud:
    """Aerial laser scan in L. xyz: (N, 3) float32 m. classification: (N,) uint8 ASPRS code."""

    xyz: np.ndarray
    classification: np.ndarray
    source_files: list[Path] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


#: Kinds of a lanelet's centre line (:meth:`Lanelet.centre`, ``[map] centre_line``): "mean"
#: midway between the other two, "resampled" the mean of the bounds resampled by arc length,
#: "lanelet2" lanelet2's ``centerline``.
CENTRE_LINES: tuple[str, ...] = ("mean", "resampled", "lanelet2")
#: A two-way lanelet (tag ``one_way`` = no / false: both directions drive it) at least this wide
#: (m) holds one lane per direction, each keeping to its right half (right-hand traffic): a
#: two-way street mapped as one lanelet. A narrower one is a single shared lane at its centre.
TWO_WAY_MIN_WIDTH: float = 5.0


@dataclass
class Lanelet:
    """One lanelet: left and right bounds as (n, 3) float64 polylines in L (z may be 0 when the
    map has no elevation), plus the OSM tags of the relation."""

    id: int
    left: np.ndarray
    right: np.ndarray
    attributes: dict[str, str] = field(default_factory=dict)
    _lanelet2_centre: np.ndarray | None = field(default=None, init=False, repr=False,
                                                compare=False)

    def polygon(self) -> np.ndarray:
        """Closed outline (left bound forward, right bound backward) as (m, 2)."""
        return np.vstack([self.left[:, :2], self.right[::-1, :2]])

    def centerline(self, n: int = 20) -> np.ndarray:
        """(n, 2) centre line from arc-length-resampled bounds."""
        return self.line_at(0.5, n)

    def lanelet2_centerline(self) -> np.ndarray:
        """(m, 2) lanelet2's own centre line of the bounds (``lanelet2.core.Lanelet.centerline``:
        midpoints between each bound's vertices and the other bound, so its vertices follow
        the bounds' nodes; not the arc-length construction of :meth:`centerline`, from which
        it lies up to 2 m away on turns drawn with few nodes); computed once."""
        if self._lanelet2_centre is None:
            from lanelet2.core import Lanelet as Lanelet2
            from lanelet2.core import LineString3d, Point3d, getId

            def line(xy: np.ndarray) -> LineString3d:
                return LineString3d(getId(), [Point3d(getId(), float(x), float(y), 0.0)
                                              for x, y in xy[:, :2]])

            c = Lanelet2(getId(), line(self.left), line(self.right)).centerline
            self._lanelet2_centre = np.array([[p.x, p.y] for p in c])
        return self._lanelet2_centre

    def centre(self, n: int, kind: str = "resampled") -> tuple[np.ndarray, np.ndarray]:
        """The centre line of ``kind`` (:data:`CENTRE_LINES`) as (n, 2) samples in the
        lanelet's direction, and (n, 2) the offset (m) from each sample of the arc-length
        construction (:meth:`centerline`) to the nearest point of lanelet2's
        (:meth:`lanelet2_centerline`): how far apart the two constructions of the centre lie
        there (half its length is the line's ambiguity). "mean" is the midpoint of those two
        points."""
        if kind not in CENTRE_LINES:
            raise ValueError(f"unknown centre line {kind!r}; expected one of "
                             f"{', '.join(CENTRE_LINES)}")
        own = self.centerline(n)
        l2 = self.lanelet2_centerline()
        offset = nearest_on_segments(own, l2[:-1], l2[1:]) - own
        line = {"resampled": own, "mean": own + 0.5 * offset}.get(kind)
        return (resample_polyline(l2, n) if line is None else line), offset

    def line_at(self, share: float | np.ndarray, n: int) -> np.ndarray:
        """(n, 2) line ``share`` of the way from the right bound (0) to the left bound (1),
        between arc-length-resampled bounds, in the lanelet's direction; ``share`` a number or
        (n,) values along the line."""
        share = np.asarray(share, dtype=float).reshape(-1, 1)
        return (share * resample_polyline(self.left[:, :2], n)
                + (1.0 - share) * resample_polyline(self.right[:, :2], n))

    def samples(self, step: float) -> int:
        """Number of samples about ``step`` m apart along the longer bound (at least 2)."""
        length = max(_length(self.left[:, :2]), _length(self.right[:, :2]))
        return max(2, int(np.ceil(length / step)) + 1)

    @property
    def two_way(self) -> bool:
        """Both directions may drive it (:func:`is_two_way` of its tags)."""
        return is_two_way(self.attributes)

    def width(self) -> float:
        """Mean distance (m) between the arc-length-resampled bounds."""
        return float(np.linalg.norm(resample_polyline(self.left[:, :2], 10)
                                    - resample_polyline(self.right[:, :2], 10), axis=1).mean())

    def keeps_right(self, two_way_min_width: float = TWO_WAY_MIN_WIDTH) -> bool:
        """A two-way lanelet wide enough for one lane per direction."""
        return self.two_way and self.width() >= two_way_min_width

    def end_gap(self) -> float:
        """The larger distance (m) between the bounds' first points and between their last
        points: a lanelet's ends are lines across the road, a few lanes long; far more means a
        bound runs on past the other (:data:`RAGGED_END_GAP`)."""
        return float(max(np.linalg.norm(self.left[0, :2] - self.right[0, :2]),
                         np.linalg.norm(self.left[-1, :2] - self.right[-1, :2])))


#: a lanelet whose bounds' ends lie more than this far apart (m, :meth:`Lanelet.end_gap`) has
#: a bound that runs on past the other: its centre line cuts across the road (the Lanelet2
#: example map has one, 102 m; its flared turns reach 17 m)
RAGGED_END_GAP = 30.0


def ragged(lanelets: list[Lanelet], limit: float = RAGGED_END_GAP) -> list[int]:
    """Ids of the lanelets whose :meth:`Lanelet.end_gap` exceeds ``limit`` m."""
    return [ll.id for ll in lanelets if ll.end_gap() > limit]


def is_two_way(tags: Mapping[str, str]) -> bool:
    """Whether a lanelet's tags let both directions drive it (``one_way`` = no / false)."""
    return tags.get("one_way", "yes").strip().lower() in ("no", "false")


def lanelets_near(lanelets: list[Lanelet], centre: np.ndarray, radius: float) -> list[Lanelet]:
    """The lanelets of ``lanelets`` whose bounding box comes within ``radius`` m of ``centre``
    (2,), in input order."""
    out = []
    for ll in lanelets:
        poly = ll.polygon()
        gap = np.maximum(0.0, np.maximum(poly.min(axis=0) - centre, centre - poly.max(axis=0)))
        if float(np.hypot(*gap)) <= radius:
            out.append(ll)
    return out


def lane_lines(lanelets: list[Lanelet], step: float,
               two_way_min_width: float = TWO_WAY_MIN_WIDTH
               ) -> list[tuple[Lanelet, np.ndarray, bool]]:
    """Where vehicles drive on the lanelets: per lane (lanelet, (n, 2) line about ``step`` m
    sampled in the driving direction, whether it runs against the lanelet's direction).

    A lanelet has one lane on its centre line (a two-way lanelet: that line in each
    direction), except a two-way lanelet at least ``two_way_min_width`` m wide
    (:data:`TWO_WAY_MIN_WIDTH`, a two-way street mapped as one lanelet): the centre of its right
    half forward, the centre of its left half backward (right-hand traffic). With
    ``two_way_min_width = inf`` every two-way lanelet is driven on its centre line both ways
    (the "centre" lane model of :mod:`fgloc.map.lane_models`). A lanelet of the list that starts
    (ends) where a right-half lane ends (starts) -- a junction lanelet leading into or out of a
    two-way street -- bends its line linearly over its length from (to) that lane's end, so the
    lane model has no jump there; the backward line of a narrower two-way lanelet bends into
    the lanes of its own direction the same way.
    """
    halves = [ll.keeps_right(two_way_min_width) for ll in lanelets]
    ends: list[tuple[np.ndarray, np.ndarray]] = []   # (first point, last point) of every lane
    for ll, half in zip(lanelets, halves):
        if half:
            for share in (0.25, 0.75):
                line = ll.line_at(share, 2)
                ends.append((line[0], line[-1]) if share == 0.25 else (line[-1], line[0]))
    starts, stops = [e[0] for e in ends], [e[1] for e in ends]
    out = []
    for ll, half in zip(lanelets, halves):
        n = ll.samples(step)
        if half:
            out += [(ll, ll.line_at(0.25, n), False), (ll, ll.line_at(0.75, n)[::-1], True)]
            continue
        # forward: from a lane that ends on the start bound, into one that starts on the end
        # bound; backward (a two-way lanelet): from a lane ending on the end bound into one
        # starting on the start bound (the other direction's lanes of the streets around)
        first = _share_on(ll.left[0, :2], ll.right[0, :2], stops)
        last = _share_on(ll.left[-1, :2], ll.right[-1, :2], starts)
        out.append((ll, ll.line_at(np.linspace(first, last, n), n), False))
        if ll.two_way:
            first = _share_on(ll.left[0, :2], ll.right[0, :2], starts)
            last = _share_on(ll.left[-1, :2], ll.right[-1, :2], stops)
            out.append((ll, ll.line_at(np.linspace(first, last, n), n)[::-1], True))
    return out


def _share_on(left: np.ndarray, right: np.ndarray, points: list[np.ndarray],
              tol: float = 0.25) -> float:
    """Share (0 = ``right``, 1 = ``left``) of the first of ``points`` within ``tol`` m of the
    segment right -> left (a lanelet's start or end bound, its end points); 0.5 when none is."""
    d = left - right
    length2 = float(d @ d)
    if length2 <= 0.0:
        return 0.5
    for p in points:
        t = float((p - right) @ d) / length2
        if 0.0 < t < 1.0 and np.linalg.norm(right + t * d - p) <= tol:
            return t
    return 0.5


def _length(p: np.ndarray) -> float:
    """Length (m) of a polyline (n, 2)."""
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def centre_ambiguity(offset: np.ndarray) -> np.ndarray:
    """(n,) the ambiguity (m) of a centre line at each sample: half the length of its offset
    (n, 2) between the two constructions (:meth:`Lanelet.centre`); a "mean" line lies that
    far from either."""
    return 0.5 * np.linalg.norm(np.asarray(offset, dtype=float), axis=1)


def lane_ambiguity(n: int, centre_offset: np.ndarray | None, bend: np.ndarray | None
                   ) -> np.ndarray:
    """(n,) how uncertain (m) it is where vehicles drive at each of n lane samples: the
    centre line's ambiguity (:func:`centre_ambiguity` of ``centre_offset`` (n, 2)) and, in
    quadrature, the ``bend`` (n,) m of a lane line that bends from its lanelet's own centre
    line into a lane before or after it (:attr:`fgloc.coarse.icp.LaneCentres.bend`: drivers
    may follow either; the whole distance, as the bent line is one of the two); None: 0."""
    a = np.zeros(n) if centre_offset is None else centre_ambiguity(centre_offset)
    return a if bend is None else np.hypot(a, np.asarray(bend, dtype=float))


def nearest_on_segments(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 2) the nearest point to each of ``xy`` (n, 2) on the segments ``a`` -> ``b``
    (m, 2 each; a segment of zero length is its point)."""
    ab = b - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    ap = xy[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("pej,ej->pe", ap, ab) / np.where(length2 > 0.0, length2, 1.0),
                0.0, 1.0)
    d = ap - t[..., None] * ab[None]
    best = np.argmin(np.einsum("pej,pej->pe", d, d), axis=1)
    return a[best] + t[np.arange(len(xy)), best, None] * ab[best]


def resample_polyline(p: np.ndarray, n: int) -> np.ndarray:
    """n points equally spaced in arc length along a polyline (m, d)."""
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return np.repeat(p[:1], n, axis=0)
    q = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(q, s, p[:, k]) for k in range(p.shape[1])])


@dataclass
class MapArea:
    """A Lanelet2 area (``type=multipolygon`` relation) fgloc does not drive on: its subtype
    (building, vegetation, walkway, parking, keepout, ...) and its outer ring (m, 2) in L."""

    id: int
    subtype: str
    outline: np.ndarray


@dataclass
class LaneletMap:
    """The lanelets a motor vehicle may drive (``lanelets``; everything fgloc computes on uses
    only these) plus what the map holds besides.

    ignored: lanelets the traffic rules close to the configured participant (crosswalks,
    walkways, bicycle lanes, rails, roads for other participants), kept for ``fgloc info`` and
    for ALS synthesis, never for localization. areas: the map's areas. successors: the routing
    graph among ``lanelets`` (lanelet id -> ids it leads to; empty when the map was not read
    with lanelet2, e.g. in memory). regulatory: regulatory elements per type (counts only).
    rules: how drivability was decided (e.g. "lanelet2 traffic rules de/vehicle").
    directed_successors: the routing graph per driving direction, (lanelet id, inverted) ->
    the (id, inverted) it leads to, where inverted = driven against the lanelet's direction
    (only two-way lanelets are; lanelet2's inverted lanelets); empty when not read from a file.
    skipped: lanelets that are roads by their tags but that lanelet2 rejected (a missing bound,
    ...), relation id -> what is wrong; they are in neither list (:meth:`warnings`).
    """

    lanelets: list[Lanelet]
    ignored: list[Lanelet] = field(default_factory=list)
    areas: list[MapArea] = field(default_factory=list)
    successors: dict[int, tuple[int, ...]] = field(default_factory=dict)
    regulatory: dict[str, int] = field(default_factory=dict)
    rules: str = "all lanelets"
    directed_successors: dict[tuple[int, bool], tuple[tuple[int, bool], ...]] = field(
        default_factory=dict)
    skipped: dict[int, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.lanelets)

    def predecessors(self) -> dict[int, tuple[int, ...]]:
        """Inverse of :attr:`successors` (lanelet id -> ids leading to it)."""
        out: dict[int, list[int]] = {}
        for a, succ in self.successors.items():
            for b in succ:
                out.setdefault(b, []).append(a)
        return {k: tuple(sorted(v)) for k, v in out.items()}

    def ignored_by_kind(self) -> dict[str, int]:
        """Number of ignored lanelets per kind (:func:`lanelet_kind`), sorted by kind."""
        kinds = [lanelet_kind(ll) for ll in self.ignored]
        return {k: kinds.count(k) for k in sorted(set(kinds))}

    def warnings(self) -> list[str]:
        """What the localization must know about the map: the roads it lacks (:attr:`skipped`)."""
        if not self.skipped:
            return []
        ids = ", ".join(str(i) for i in sorted(self.skipped))
        return [f"map: {len(self.skipped)} lanelet(s) that are roads by their tags were "
                f"skipped, lanelet2 rejected them (relation {ids}; first: "
                f"{next(iter(self.skipped.values()))}); vehicles driving there have no road to "
                "be registered to"]

    def areas_by_kind(self) -> dict[str, int]:
        """Number of areas per subtype, sorted by subtype."""
        kinds = [a.subtype for a in self.areas]
        return {k: kinds.count(k) for k in sorted(set(kinds))}


def lanelet_kind(lanelet: Lanelet) -> str:
    """A lanelet's kind as counted by ``fgloc info``: its subtype (``road`` when untagged), with
    `` (participants: a, b)`` appended when ``participant:*=yes`` tags restrict it."""
    sub = lanelet.attributes.get("subtype", "road")
    allowed = sorted(k.split(":", 1)[1] for k, v in lanelet.attributes.items()
                     if k.startswith("participant:") and v == "yes")
    return f"{sub} (participants: {', '.join(allowed)})" if allowed else sub


@dataclass
class MapSettings:
    """sensor.toml's ``[map]`` table: how the scenario's Lanelet2 map is read.

    location / participant: lanelet2 traffic rules deciding which lanelets are drivable
    (``lanelet2.traffic_rules.create(location, participant)``; "de" and "vehicle" by default,
    e.g. "vehicle:truck"); where lanelet2 has no rules for them, the subtype and participant
    tags decide. local_crs / local_offset: for maps whose nodes carry ``local_x`` /
    ``local_y`` tags (Autoware style, m): the projected CRS of those coordinates and the
    coordinates (E, N, m, in local_crs) of their origin; None = use the nodes' lat/lon.
    """

    location: str = "de"
    participant: str = "vehicle"
    local_crs: str | None = None
    local_offset: tuple[float, float] = (0.0, 0.0)


@dataclass
class SensorConfig:
    """sensor.toml. approx_position is (E, N) in the world CRS; angles in degrees as written.

    ``crs`` is None when the file has none; the world CRS then comes from the ALS tiles and the
    resolved value is :attr:`Scenario.crs`.
    """

    approx_position: tuple[float, float]
    crs: str | None = None
    approx_height: float | None = None
    yaw_guess_deg: float | None = None
    hfov_deg: float = 120.0
    vfov_deg: float = 30.0
    max_range: float = 250.0
    map: MapSettings = field(default_factory=MapSettings)


@dataclass
class TrackTruth:
    """A true vehicle. states: (n, 6) [t, x, y, yaw, v, yawrate] with x, y in L, yaw rad CCW
    from grid east, v m/s, yawrate rad/s. length, width in metres."""

    id: int
    length: float
    width: float
    states: np.ndarray


@dataclass
class GroundTruth:
    """Ground truth in L. sensor_pose: 4x4 transform S -> L."""

    crs: str
    sensor_pose: np.ndarray
    tracks: list[TrackTruth] = field(default_factory=list)


@dataclass
class Scenario:
    """A whole scenario directory, loaded. ``frame`` maps every L quantity back to the world."""

    frame: LocalFrame
    sensor: SensorConfig
    radar: RadarData
    als: AlsCloud
    lanelets: LaneletMap
    truth: GroundTruth | None = None
    path: Path | None = None

    @property
    def crs(self) -> str:
        return self.frame.crs
