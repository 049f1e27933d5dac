"""Two-way streets mapped as one lanelet (``one_way`` = no), as real Lanelet2 maps have them.

The Lanelet2 example map draws many two-way streets as one 6-7.5 m wide lanelet; vehicles keep
to the right half in their direction. The lane models must put a lane per direction there (not
one lane on the centre line, 1.5-1.9 m beside where the vehicles drive) and the simulator must
drive it so.
"""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.coarse import LaneCentres
from fgloc.config import Config
from fgloc.geo import se2, transform_points
from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.map import TargetCloud
from fgloc.registration.fine import centre_weights, fine_sicp_config, lane_centre_points
from fgloc.registration.sicp import SemanticTargets, sicp
from fgloc.scenario import Lanelet, LaneletMap, centre_ambiguity, lane_lines
from fgloc.sim.real_roads import _polyline


def _street(lid: int, start: tuple[float, float], heading_deg: float, length: float,
            width: float, one_way: str) -> Lanelet:
    """A straight lanelet ``width`` m wide from ``start`` along ``heading_deg``."""
    h = np.deg2rad(heading_deg)
    d, n = np.array([np.cos(h), np.sin(h)]), np.array([-np.sin(h), np.cos(h)])
    s = np.linspace(0.0, length, 2)[:, None]
    axis = np.asarray(start) + s * d
    z = np.zeros((2, 1))
    return Lanelet(lid, np.hstack([axis + 0.5 * width * n, z]),
                   np.hstack([axis - 0.5 * width * n, z]),
                   {"type": "lanelet", "subtype": "road", "one_way": one_way})


def _arc(lid: int, radius: float, width: float, one_way: str) -> Lanelet:
    """A quarter circle to the left (counter-clockwise) around the origin, ``width`` m wide."""
    a = np.linspace(-np.pi / 2, 0.0, 30)
    ring = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    return Lanelet(lid, ring * [radius - width / 2, radius - width / 2, 0],
                   ring * [radius + width / 2, radius + width / 2, 0], {"one_way": one_way})


@pytest.mark.parametrize(("width", "one_way", "min_width", "lanes", "offset"),
                         [(7.0, "no", 5.0, 2, 7.0 / 4), (7.0, "false", 5.0, 2, 7.0 / 4),
                          (4.0, "no", 5.0, 2, 0.0), (7.0, "no", np.inf, 2, 0.0),
                          (7.0, "yes", 5.0, 1, 0.0)])
def test_lane_lines_of_two_way_and_one_way_lanelets(width: float, one_way: str,
                                                    min_width: float, lanes: int,
                                                    offset: float) -> None:
    """One-way: the centre line. Two-way: a line per direction, on the centre of each
    direction's right half when at least ``min_width`` wide (keep right), else (or with the
    "centre" model, min_width inf) on the centre line both ways."""
    ll = _street(1, (0.0, 0.0), 0.0, 40.0, width, one_way)
    lines = lane_lines([ll], 10.0, min_width)
    assert len(lines) == lanes and all(owner is ll for owner, _, _ in lines)
    if lanes == 1:
        np.testing.assert_allclose(lines[0][1][:, 1], 0.0, atol=1e-12)
        assert not lines[0][2]
        return
    (_, fwd, back_fwd), (_, rev, back_rev) = lines
    # forward on y = -offset (right half's centre or the centre line), backward on +offset
    np.testing.assert_allclose(fwd[:, 1], -offset, atol=1e-12)
    np.testing.assert_allclose(rev[:, 1], offset, atol=1e-12)
    assert fwd[-1, 0] > fwd[0, 0] and rev[-1, 0] < rev[0, 0]
    assert (back_fwd, back_rev) == (False, True)


def test_lane_centres_face_each_lane_direction() -> None:
    lc = LaneCentres.build([_street(1, (0.0, 0.0), 0.0, 20.0, 7.0, "no")], 0.5)
    fwd, rev = ~lc.against, lc.against
    assert fwd.sum() == rev.sum() > 0
    np.testing.assert_allclose(lc.normal[fwd], [[0.0, 1.0]] * int(fwd.sum()), atol=1e-9)
    np.testing.assert_allclose(lc.normal[rev], [[0.0, -1.0]] * int(rev.sum()), atol=1e-9)


def _scene(lanelets: list[Lanelet], labels: dict[int, int]) -> tuple[object, TargetCloud]:
    """A stand-in scenario (only ``lanelets`` is read) and a target cloud naming the lanelets."""
    class _Scn:
        pass
    scn = _Scn()
    scn.lanelets = LaneletMap(lanelets)
    ids = np.array([ll.id for ll in lanelets], dtype=np.int64)
    target = TargetCloud(np.zeros((len(ids), 3)), np.array([labels[i] for i in ids], np.int8),
                         ids, labels)
    return scn, target


def test_lane_centres_of_a_target_are_built_once_per_setting_and_read_only() -> None:
    """:meth:`LaneCentres.of_target` equals :meth:`LaneCentres.build` on the target's
    lanelets, returns the same object for the same map and setting (the valley's probes ask
    60 times), a new one for another lane model, step or map, and no caller can change it."""
    street, turn = _street(1, (0.0, 0.0), 0.0, 20.0, 7.0, "no"), _arc(7, 12.0, 7.0, "no")
    scn, target = _scene([street, turn], {1: STRAIGHT, 7: LEFT})
    lanes = LaneCentres.of_target(target, scn.lanelets, 0.5, 6.0, "resampled")
    built = LaneCentres.build([street, turn], 0.5, 6.0, "resampled")
    for name, value in vars(built).items():
        np.testing.assert_array_equal(getattr(lanes, name), value, err_msg=name)
    assert LaneCentres.of_target(target, scn.lanelets, 0.5, 6.0, "resampled") is lanes
    centre_model = LaneCentres.of_target(target, scn.lanelets, 0.5, np.inf, "resampled")
    assert np.abs(centre_model.xy - lanes.xy).max() > 1.0    # both directions on the centre
    assert LaneCentres.of_target(target, scn.lanelets, 1.0, 6.0, "resampled") is not lanes
    other_map = LaneletMap([street, turn])
    assert LaneCentres.of_target(target, other_map, 0.5, 6.0, "resampled") is not lanes
    with pytest.raises(ValueError, match="read-only"):
        lanes.xy[0, 0] = 1.0


def test_lane_against_a_turning_lanelet_takes_the_mirrored_label() -> None:
    turn = _arc(7, 12.0, 7.0, "no")
    scn, target = _scene([turn], {7: LEFT})
    xy, label, _, _, _ = lane_centre_points(scn, target, 0.5)
    r = np.hypot(xy[:, 0], xy[:, 1])
    # keeping right, the lanelet's own direction (a left turn) takes the outer half (radius
    # 12 + 1.75), the other direction the inner half, turning right
    np.testing.assert_array_equal(label[r > 12.0], LEFT)
    np.testing.assert_array_equal(label[r < 12.0], RIGHT)
    # (the arc is a 30-point polygon: its chords lie up to 3 cm inside the circle)
    assert np.all(np.minimum(np.abs(r - 10.25), np.abs(r - 13.75)) < 0.04)
    assert (r > 12.0).sum() == (r < 12.0).sum()


def test_fine_registration_on_two_way_streets_recovers_the_true_pose() -> None:
    """Vehicles keep right on two two-way streets (an L); their points registered to the lane
    model from a known offset come back to the truth. With one lane on each street's centre
    line (the old model) the result is pulled ~w/4 = 1.75 m sideways."""
    w = 7.0
    streets = [_street(1, (0.0, 0.0), 0.0, 80.0, w, "no"),
               _street(2, (0.0, -40.0), 90.0, 80.0, w, "no")]
    scn, target = _scene(streets, {1: STRAIGHT, 2: STRAIGHT})
    rng = np.random.default_rng(4)
    # traffic in each street's own direction only (as on a one-directional stretch of a day)
    along = np.linspace(0.0, 80.0, 400)
    truth = np.vstack([np.column_stack([along, np.full(400, -w / 4)]),          # eastbound
                       np.column_stack([np.full(400, w / 4), along - 40.0])])   # northbound
    truth = truth + rng.normal(0.0, 0.15, truth.shape)
    T_err = se2(0.4, -0.3, np.deg2rad(0.5))
    src = transform_points(np.linalg.inv(T_err), truth)
    cfg = Config()
    res = sicp(src, np.full(len(src), STRAIGHT), SemanticTargets.build(
        *lane_centre_points(scn, target, cfg.fine.lane_sample_step)[:3]), None, np.eye(3),
        fine_sicp_config(cfg))
    err = transform_points(res.T, src) - truth
    assert np.abs(err.mean(axis=0)).max() < 0.05
    assert np.sqrt((err**2).sum(axis=1).mean()) < 0.25


def test_simulated_routes_keep_right_on_a_two_way_street() -> None:
    street = _street(1, (0.0, 0.0), 0.0, 60.0, 7.0, "no")
    xy = _polyline([street], "centre")
    np.testing.assert_allclose(xy[:, 1], -1.75, atol=1e-9)
    one_way = _street(2, (0.0, 0.0), 0.0, 60.0, 7.0, "yes")
    np.testing.assert_allclose(_polyline([one_way], "centre")[:, 1], 0.0, atol=1e-9)


def test_junction_lanelet_bends_into_the_two_way_streets_lane() -> None:
    """A one-way junction lanelet (4 m wide) ending on the start bound of a two-way street
    (7 m): its lane runs from its own centre to the street's right half, no jump at the join."""
    street = _street(2, (20.0, 0.0), 0.0, 40.0, 7.0, "no")
    z = np.zeros((3, 1))
    x = np.array([[0.0], [10.0], [20.0]])
    # widening from 4 m to the street's whole start bound (y = 3.5 to -3.5)
    junction = Lanelet(1, np.hstack([x, [[2.0], [2.75], [3.5]], z]),
                       np.hstack([x, [[-2.0], [-2.75], [-3.5]], z]), {"one_way": "yes"})
    lines = {(ll.id, back): c for ll, c, back in lane_lines([junction, street], 1.0)}
    bend = lines[(1, False)]
    np.testing.assert_allclose(bend[0], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(bend[-1], lines[(2, False)][0], atol=1e-9)
    np.testing.assert_allclose(bend[-1], [20.0, -1.75], atol=1e-9)
    # alone (no street after it) it keeps its centre line
    np.testing.assert_allclose(lane_lines([junction], 1.0)[0][1][:, 1], 0.0, atol=1e-9)
    route = _polyline([junction, street], "centre")
    step = np.linalg.norm(np.diff(route, axis=0), axis=1)
    assert step.max() < 1.05     # no jump at the join (1 m resampling)
    np.testing.assert_allclose(route[-10:, 1], -1.75, atol=1e-6)


@pytest.mark.parametrize("gate_deg", [180.0, 90.0])
def test_sicp_matches_points_to_the_lane_of_their_direction(gate_deg: float) -> None:
    """Two two-way streets crossing (lanes 2.5 m apart), traffic seen in one direction on each;
    started 1.4 m towards the other lanes, SICP with directions (the default 90 deg gate) comes back
    to the truth; without them (the old matching) points match the other direction's lanes
    and the pose stays off (0.13 m in this setting)."""
    import dataclasses

    lanes_xy, lanes_dir = [], []
    s = np.linspace(-40.0, 40.0, 321)
    for xy, d in ((np.column_stack([s, np.full_like(s, -1.25)]), (1.0, 0.0)),
                  (np.column_stack([s, np.full_like(s, 1.25)]), (-1.0, 0.0)),
                  (np.column_stack([np.full_like(s, 1.25), s]), (0.0, 1.0)),
                  (np.column_stack([np.full_like(s, -1.25), s]), (0.0, -1.0))):
        lanes_xy.append(xy)
        lanes_dir.append(np.tile(d, (len(s), 1)))
    xy, direction = np.vstack(lanes_xy), np.vstack(lanes_dir)
    targets = SemanticTargets.build(xy, np.full(len(xy), STRAIGHT), direction)
    truth, truth_dir = np.vstack([lanes_xy[0], lanes_xy[2]]), np.vstack([lanes_dir[0],
                                                                       lanes_dir[2]])
    T_err = se2(-1.4, 1.4, 0.0)
    src = transform_points(np.linalg.inv(T_err), truth)
    cfg = dataclasses.replace(fine_sicp_config(Config()), direction_gate_deg=gate_deg)
    res = sicp(src, np.full(len(src), STRAIGHT), targets, None, np.eye(3), cfg,
               source_direction=truth_dir)
    err = np.abs(transform_points(res.T, src) - truth).mean(axis=0)
    if gate_deg < 180.0:
        assert err.max() < 0.01
    else:
        assert err.max() > 0.1      # pulled towards the lanes of the other direction


@pytest.mark.parametrize("traffic", ["keep-right", "centre"])
def test_the_tracks_choose_the_lane_model_of_their_traffic(traffic: str) -> None:
    """Two two-way streets (7 m, one lanelet each) in an L, vehicles in both directions on
    each, driving either keep-right lanes or the centre line. Registered once per lane model
    (:mod:`fgloc.map.lane_models`) from the same offset start and compared per track with the
    direction-gated cost, the model of the traffic wins, resolved, at the true pose; the other
    model's fit is metres off at the points (turned by 4-6 deg). (The keep-right model on
    centre-line traffic ends where one direction per street fits: half the tracks prefer the
    centre model, the others are indifferent, so the evidence grows as the square root of
    their number: 12 tracks give z = 3.5 against ``coarse.mode_z`` = 3.)"""
    from fgloc.map.lane_models import MODELS, min_width
    from fgloc.registration.modes import ModeFit, choose_mode, track_costs
    from fgloc.registration.source import SourceCloud

    w = 7.0
    streets = [_street(1, (0.0, 0.0), 0.0, 80.0, w, "no"),
               _street(2, (0.0, -40.0), 90.0, 80.0, w, "no")]
    scn, target = _scene(streets, {1: STRAIGHT, 2: STRAIGHT})
    cfg = Config()
    rng = np.random.default_rng(11)
    off = w / 4 if traffic == "keep-right" else 0.0
    pts, dirs, ids = [], [], []
    for k in range(24):           # 6 vehicles per direction and street, 20 m of track each
        street, back = k // 12, k % 2 == 1
        s = rng.uniform(5.0, 55.0) + np.linspace(0.0, 20.0, 40)
        side = off if back else -off           # right of the driving direction
        xy = (np.column_stack([s, np.full(40, side)]) if street == 0
              else np.column_stack([np.full(40, -side), s - 40.0]))
        d = np.array([1.0, 0.0]) if street == 0 else np.array([0.0, 1.0])
        pts.append(xy + rng.normal(0.0, 0.15, xy.shape))
        dirs.append(np.tile(-d if back else d, (40, 1)))
        ids.append(np.full(40, k))
    truth = np.vstack(pts)
    T_err = se2(0.5, -0.4, np.deg2rad(0.4))
    src = SourceCloud(transform_points(np.linalg.inv(T_err), truth),
                      np.full(len(truth), STRAIGHT, np.int8), np.concatenate(ids), "detections",
                      24, 24, len(truth), np.vstack(dirs) @ T_err[:2, :2])
    fits = []
    for model in MODELS:
        cfg.map.two_way_lanes = model
        width = min_width(model, cfg.map.two_way_min_width)
        targets = SemanticTargets.build(*lane_centre_points(
            scn, target, cfg.fine.lane_sample_step, two_way_min_width=width)[:3])
        res = sicp(src.xy, src.label, targets, None, np.eye(3), fine_sicp_config(cfg),
                   source_direction=src.direction)
        T_local = np.eye(4)
        T_local[:2, :2], T_local[:2, 3] = res.T[:2, :2], res.T[:2, 2]
        fits.append(ModeFit(res.T, T_local, None, track_costs(
            src, targets, res.T, cfg.coarse.mode_cost_scale, cfg.sicp.direction_gate_deg),
            1.0, res.converged, np.eye(3), None, model))
    choice = choose_mode(fits, cfg.coarse)
    assert choice.best.lanes == traffic and choice.status == "resolved"
    err = transform_points(choice.best.T_fine, src.xy) - truth
    assert np.hypot(*err.mean(axis=0)) < 0.05
    other = next(f for f in fits if f.lanes != traffic)
    off = transform_points(other.T_fine, src.xy) - truth     # turned 4-6 deg: RMS, not mean
    assert np.sqrt(np.mean(np.sum(off**2, axis=1))) > 0.5


def test_narrow_two_way_lanelet_bends_each_direction_into_its_own_lane() -> None:
    """A narrow two-way lanelet (3 m, both ways on its centre line) ending on the start bound of
    a wide two-way street (7 m, keep right): its forward line bends into the street's forward
    lane (right half, y = -1.75), its backward line comes out of the street's backward lane
    (left half, y = +1.75) -- where the simulator's inverted lanelets drive them."""
    street = _street(2, (20.0, 0.0), 0.0, 40.0, 7.0, "no")
    z = np.zeros((3, 1))
    x = np.array([[0.0], [10.0], [20.0]])
    # 3 m wide, widening to the street's whole start bound over its last 10 m (mean < 5 m)
    link = Lanelet(1, np.hstack([x, [[1.5], [1.5], [3.5]], z]),
                   np.hstack([x, [[-1.5], [-1.5], [-3.5]], z]), {"one_way": "no"})
    assert not link.keeps_right()
    lines = {(ll.id, back): c for ll, c, back in lane_lines([link, street], 1.0)}
    fwd, back = lines[(1, False)], lines[(1, True)]
    np.testing.assert_allclose(fwd[0], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(fwd[-1], lines[(2, False)][0], atol=1e-9)
    np.testing.assert_allclose(back[0], lines[(2, True)][-1], atol=1e-9)
    np.testing.assert_allclose(back[0], [20.0, 1.75], atol=1e-9)
    np.testing.assert_allclose(back[-1], [0.0, 0.0], atol=1e-9)
    assert back[-1, 0] < back[0, 0]                 # driven against the lanelet's direction
    # the centre model: no halves, no bends, the centre line both ways
    centre = {(ll.id, b): c for ll, c, b in lane_lines([link, street], 1.0, np.inf)}
    np.testing.assert_allclose(centre[(1, True)][:, 1], 0.0, atol=1e-9)


def test_a_bent_lane_is_as_ambiguous_as_it_is_far_from_its_lanelets_centre() -> None:
    """Where a lane bends from its lanelet's centre line into a neighbour's lane, drivers may
    follow either line: the bend (the distance to the lanelet's own centre line) is the
    lane's ambiguity there (in quadrature with the centre line's), which weighs its samples
    down in SICP and grows the joint's point noise; the halves of a two-way street and
    the "centre" model have none."""
    street = _street(2, (20.0, 0.0), 0.0, 40.0, 7.0, "no")
    z = np.zeros((3, 1))
    x = np.array([[0.0], [10.0], [20.0]])
    link = Lanelet(1, np.hstack([x, [[1.5], [1.5], [3.5]], z]),
                   np.hstack([x, [[-1.5], [-1.5], [-3.5]], z]), {"one_way": "no"})
    lanes = LaneCentres.build([link, street], 1.0, centre="resampled")
    on_link = lanes.lanelet == 0
    # the link's own centre line is y = 0: the bend is the lane's |y|, measured across the
    # lane (which turns by up to 10 deg here: cos 10 deg = 0.985)
    np.testing.assert_allclose(lanes.bend[on_link], np.abs(lanes.xy[on_link, 1]), rtol=0.02)
    assert lanes.bend[on_link].max() == pytest.approx(1.75, rel=0.02)
    assert lanes.bend[on_link].min() == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(lanes.bend[~on_link], 0.0)        # the street's halves
    np.testing.assert_allclose(lanes.ambiguity(), np.hypot(
        centre_ambiguity(lanes.centre_offset), lanes.bend), atol=1e-12)
    centre = LaneCentres.build([link, street], 1.0, np.inf, centre="resampled")
    np.testing.assert_allclose(centre.bend, 0.0, atol=1e-9)
    # SICP's lane samples: weight sigma^2 / (sigma^2 + bend^2)
    labels = {1: STRAIGHT, 2: STRAIGHT}
    scn, target = _scene([link, street], labels)
    cfg = Config()
    _, _, _, ambiguity, _ = lane_centre_points(scn, target, 1.0, centre="resampled")
    np.testing.assert_allclose(np.sort(ambiguity), np.sort(lanes.ambiguity()), atol=1e-9)
    w = centre_weights(ambiguity, cfg.fine.centre_weight_sigma)
    sigma2 = cfg.fine.centre_weight_sigma**2
    np.testing.assert_allclose(np.sort(w), np.sort(sigma2 / (sigma2 + lanes.ambiguity()**2)))
    assert w.min() <= sigma2 / (sigma2 + 1.7**2)
