"""Real Lanelet2 maps: drivable lanelets only, routing-graph labels, robust reading.

Uses a crop of the official Lanelet2 example map (tests/data/lanelet2_example_crop.osm,
BSD-3-Clause, copyright 2018 FZI, see tests/data/LICENSE-lanelet2_mapping_example).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import lanelet2
import numpy as np
import pytest
from lanelet2.io import Origin
from lanelet2.projection import UtmProjector

from fgloc.config import Config, MapConfig
from fgloc.errors import InputError
from fgloc.geo import LocalFrame, transformer, wrap_angle
from fgloc.io.lanelet_map import als_ground, passable_by_tags, read_lanelet_map
from fgloc.io.sensor_file import read_sensor_toml, write_sensor_toml
from fgloc.labels import LEFT, RIGHT, STRAIGHT, junction_movements, routing_labels
from fgloc.map import build_target_cloud, map_labels, points_in_polygon
from fgloc.registration.fine import centre_weights, fine_targets, lane_centre_points
from fgloc.scenario import (
    AlsCloud,
    Lanelet,
    LaneletMap,
    MapSettings,
    RadarData,
    Scenario,
    SensorConfig,
    resample_polyline,
)

DATA = Path(__file__).parent / "data"
CROP = DATA / "lanelet2_example_crop.osm"
CRS = "EPSG:25832"
#: junction of the crop (lat, lon) and a frame near it
SITE = (49.00519, 8.415632)


def site_frame(z0: float = 0.0) -> LocalFrame:
    e, n = transformer("EPSG:4326", CRS).transform(SITE[1], SITE[0])
    return LocalFrame.around(e, n, z0, CRS)


@pytest.fixture(scope="module")
def crop_map() -> LaneletMap:
    return read_lanelet_map(CROP, CRS, site_frame())


def lanelet2_passable(path: Path, location: str, participant: str) -> dict[int, bool]:
    """canPass of every lanelet, straight from lanelet2 (the reference)."""
    lmap = lanelet2.io.load(str(path), UtmProjector(Origin(*SITE)))
    rules = lanelet2.traffic_rules.create(location, participant)
    return {ll.id: bool(rules.canPass(ll)) for ll in lmap.laneletLayer}


# --------------------------------------------------------------------------------------------
# drivable lanelets
# --------------------------------------------------------------------------------------------
def test_crop_keeps_only_what_lanelet2_lets_a_vehicle_pass(crop_map: LaneletMap) -> None:
    ref = lanelet2_passable(CROP, "de", "vehicle")
    assert {ll.id for ll in crop_map.lanelets} == {i for i, ok in ref.items() if ok}
    assert {ll.id for ll in crop_map.ignored} == {i for i, ok in ref.items() if not ok}
    kinds = crop_map.ignored_by_kind()
    for kind in ("crosswalk", "bicycle_lane", "rail", "road (participants: bicycle, pedestrian)"):
        assert kinds.get(kind, 0) > 0, kinds
    assert {ll.attributes.get("subtype") for ll in crop_map.lanelets} <= {"road", "highway"}
    assert crop_map.rules == "lanelet2 traffic rules de/vehicle"
    assert crop_map.areas_by_kind().get("vegetation", 0) > 0
    assert crop_map.regulatory  # counted, not fatal


@pytest.mark.parametrize("participant", ["bicycle", "pedestrian"])
def test_participant_is_configurable(participant: str) -> None:
    lmap = read_lanelet_map(CROP, CRS, site_frame(), settings=MapSettings(participant=participant))
    ref = lanelet2_passable(CROP, "de", participant)
    assert {ll.id for ll in lmap.lanelets} == {i for i, ok in ref.items() if ok}
    wanted = "bicycle_lane" if participant == "bicycle" else "crosswalk"
    assert wanted in {ll.attributes.get("subtype") for ll in lmap.lanelets}


def test_unknown_location_falls_back_to_tags(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING):
        lmap = read_lanelet_map(CROP, CRS, site_frame(), settings=MapSettings(location="xx"))
    assert "No matching traffic rules" in caplog.text
    assert lmap.rules.startswith("subtype/participant tags")
    ref = lanelet2_passable(CROP, "de", "vehicle")  # the tags say what Germany's rules say here
    assert {ll.id for ll in lmap.lanelets} == {i for i, ok in ref.items() if ok}
    # the fallback finds the same routing graph (shared bound points)
    assert lmap.successors == read_lanelet_map(CROP, CRS, site_frame()).successors


@pytest.mark.parametrize(
    ("tags", "participant", "expected"),
    [({"subtype": "road"}, "vehicle", True),
     ({"subtype": "road"}, "vehicle:car", True),
     ({"subtype": "crosswalk"}, "vehicle", False),
     ({"subtype": "crosswalk"}, "pedestrian", True),
     ({"subtype": "bicycle_lane"}, "vehicle", False),
     ({"subtype": "road", "participant:bicycle": "yes"}, "vehicle", False),
     ({"subtype": "road", "participant:vehicle": "yes"}, "vehicle:truck", True),
     ({"subtype": "walkway", "participant:vehicle:car": "yes"}, "vehicle:car", True),
     ({"subtype": "road", "participant:vehicle": "no"}, "vehicle", False),
     ({}, "vehicle", True)],
)
def test_passable_by_tags(tags: dict[str, str], participant: str, expected: bool) -> None:
    assert passable_by_tags(tags, participant) is expected


def flat_scenario(lmap: LaneletMap, frame: LocalFrame, spacing: float = 1.0) -> Scenario:
    """A scenario whose ALS is a grid of road-surface points over the whole map (every
    polygon, drivable or not, is covered), sensor at the crop's junction."""
    xy = np.vstack([ll.polygon() for ll in lmap.lanelets + lmap.ignored])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], spacing), np.arange(lo[1], hi[1], spacing))
    pts = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]).astype(np.float32)
    als = AlsCloud(pts, np.full(len(pts), 11, dtype=np.uint8))
    sensor = SensorConfig(approx_position=tuple(frame.origin[:2]), crs=CRS, max_range=150.0)
    radar = RadarData(np.zeros(0), np.zeros((0, 3)), np.zeros(0))
    return Scenario(frame=frame, sensor=sensor, radar=radar, als=als, lanelets=lmap)


def inside_any(xy: np.ndarray, lanelets: list[Lanelet], margin: float = 0.01) -> np.ndarray:
    """Points inside (or within ``margin`` m of) any of the lanelets' polygons."""
    out = np.zeros(len(xy), dtype=bool)
    for ll in lanelets:
        out |= points_in_polygon(xy, ll.polygon(), margin)
    return out


def test_no_target_point_on_crosswalk_walkway_or_bicycle_lane(crop_map: LaneletMap) -> None:
    scn = flat_scenario(crop_map, site_frame())
    target = build_target_cloud(scn, MapConfig())
    drivable = {ll.id for ll in crop_map.lanelets}
    assert set(np.unique(target.lanelet_id).tolist()) <= drivable
    others = [ll for ll in crop_map.ignored
              if ll.attributes.get("subtype") in ("crosswalk", "walkway", "bicycle_lane")]
    assert others
    on_other = inside_any(target.xyz[:, :2], others)
    # the ALS grid covers the non-drivable lanelets: off the road they give no target point,
    # where a crosswalk crosses the road its points belong to the road lanelets only
    grid = scn.als.xyz[:, :2].astype(float)
    assert (inside_any(grid, others) & ~inside_any(grid, crop_map.lanelets)).sum() > 100
    assert not (on_other & ~inside_any(target.xyz[:, :2], crop_map.lanelets)).any()
    summary = target.summary()
    assert summary["ignored_lanelets"] == crop_map.ignored_by_kind()
    # what coarse, fine and joint build their lane models from: drivable lanelets only
    lane_xy = lane_centre_points(scn, target, 2.0)[0]
    assert inside_any(lane_xy, crop_map.lanelets).all()
    assert not (inside_any(lane_xy, others) & ~inside_any(lane_xy, crop_map.lanelets)).any()


def test_sicp_lane_targets_carry_the_centre_weights(crop_map: LaneletMap) -> None:
    """filter-sicp's lane target on the crop: each sample weighs by its centre line's
    ambiguity (``[fine] centre_weight_sigma``); the crop's hand-mapped turns weigh less."""
    scn = flat_scenario(crop_map, site_frame())
    target = build_target_cloud(scn, MapConfig())
    cfg = Config()
    targets = fine_targets(scn, target, cfg, np.zeros(2))
    amb = lane_centre_points(scn, target, cfg.fine.lane_sample_step, np.zeros(2),
                             cfg.coarse.visible_side_offset, centre=cfg.map.centre_line)[3]
    np.testing.assert_allclose(targets.weight, centre_weights(amb, cfg.fine.centre_weight_sigma))
    assert (targets.weight < 0.5).mean() > 0.01 and np.median(targets.weight) > 0.9
    cfg.fine.centre_weight_sigma = 0.0
    assert fine_targets(scn, target, cfg, np.zeros(2)).weight is None


# --------------------------------------------------------------------------------------------
# labels: routing graph against Menger curvature
# --------------------------------------------------------------------------------------------
def straight(p0: tuple[float, float], heading_deg: float, length: float, n: int) -> np.ndarray:
    h = np.deg2rad(heading_deg)
    s = np.linspace(0.0, length, n)
    return np.column_stack([p0[0] + s * np.cos(h), p0[1] + s * np.sin(h), np.zeros(n)])


def lanelet_on(centre: np.ndarray, lid: int, width: float = 3.5, chord: bool = False) -> Lanelet:
    """Lanelet of ``width`` around a centre line; ``chord`` draws each bound with its two end
    points only (as hand-mapped junction lanelets often are)."""
    d = np.gradient(centre[:, :2], axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = np.column_stack([-d[:, 1], d[:, 0], np.zeros(len(d))])
    left, right = centre + 0.5 * width * n, centre - 0.5 * width * n
    if chord:
        left, right = left[[0, -1]], right[[0, -1]]
    return Lanelet(lid, left, right, {"subtype": "road"})


def junction_map(chord_turns: bool) -> tuple[LaneletMap, dict[int, int]]:
    """An approach from the west into a junction at the origin with a straight, a left turn
    (r = 12 m) and a right turn (r = 8 m) into exit roads; the true label of each lanelet."""
    approach = straight((-60.0, -1.75), 0.0, 50.0, 11)        # ends at (-10, -1.75)
    through = straight((-10.0, -1.75), 0.0, 20.0, 5)
    th = np.linspace(0.0, np.pi / 2, 15)
    left = np.column_stack([-10.0 + 12 * np.sin(th), -1.75 + 12 * (1 - np.cos(th)), 0 * th])
    right = np.column_stack([-10.0 + 8 * np.sin(th), -1.75 - 8 * (1 - np.cos(th)), 0 * th])
    east = straight((10.0, -1.75), 0.0, 50.0, 11)
    north = straight(tuple(left[-1, :2]), 90.0, 50.0, 11)
    south = straight(tuple(right[-1, :2]), -90.0, 50.0, 11)
    lls = [lanelet_on(approach, 1), lanelet_on(through, 2),
           lanelet_on(left, 3, chord=chord_turns), lanelet_on(right, 4, chord=chord_turns),
           lanelet_on(east, 5), lanelet_on(north, 6), lanelet_on(south, 7)]
    succ = {1: (2, 3, 4), 2: (5,), 3: (6,), 4: (7,)}
    truth = {1: STRAIGHT, 2: STRAIGHT, 3: LEFT, 4: RIGHT, 5: STRAIGHT, 6: STRAIGHT, 7: STRAIGHT}
    return LaneletMap(lls, successors=succ), truth


@pytest.mark.parametrize("chord_turns", [False, True], ids=["arcs", "chords"])
def test_routing_labels_against_menger_curvature(chord_turns: bool) -> None:
    lmap, truth = junction_map(chord_turns)
    assert sorted(junction_movements(lmap)) == [[2, 5], [3, 6], [4, 7]]  # exits run on
    routed = map_labels(lmap, MapConfig(labels="routing")).code
    menger = map_labels(lmap, MapConfig(labels="curvature")).code
    assert routed == truth  # the routing graph is right whichever way the bounds are drawn
    if chord_turns:  # two-point bounds: Menger sees straight lines
        assert menger[3] == STRAIGHT and menger[4] == STRAIGHT
    else:
        assert menger == truth


def test_split_turn_and_exit_road_in_one_movement() -> None:
    """A 90 deg left turn drawn as three lanelets running on into the exit road without a
    branch: the three turn pieces are left, the exit pieces straight."""
    th = np.linspace(0.0, np.pi / 2, 31)
    arc = np.column_stack([12 * np.sin(th), 12 * (1 - np.cos(th)), 0 * th])
    lls = [lanelet_on(straight((-40.0, 0.0), 0.0, 40.0, 9), 1),
           lanelet_on(straight((0.0, 0.0), 0.0, 30.0, 7), 2)]
    lls += [lanelet_on(arc[10 * k: 10 * k + 11], 3 + k) for k in range(3)]
    lls += [lanelet_on(straight((12.0, 12.0 + 20 * k), 90.0, 20.0, 5), 6 + k) for k in range(2)]
    succ = {1: (2, 3), 3: (4,), 4: (5,), 5: (6,), 6: (7,)}
    labels = routing_labels(LaneletMap(lls, successors=succ), np.deg2rad(30.0))
    assert labels == {2: STRAIGHT, 3: LEFT, 4: LEFT, 5: LEFT, 6: STRAIGHT, 7: STRAIGHT}


def test_routing_labels_on_the_example_crop(crop_map: LaneletMap) -> None:
    """On the real crop: junction movements exist and are labelled from the routing graph; a
    movement lanelet that itself turns by more than 60 deg is never called straight."""
    labels = map_labels(crop_map, MapConfig())
    routed = [i for i, s in labels.source.items() if s == "routing"]
    assert len(junction_movements(crop_map)) >= 5 and routed
    by_id = {ll.id: ll for ll in crop_map.lanelets}
    for lid in routed:
        c = by_id[lid].centerline(20)
        d0, d1 = c[1] - c[0], c[-1] - c[-2]
        own = np.degrees(np.arctan2(d0[0] * d1[1] - d0[1] * d1[0], d0 @ d1))
        if abs(own) > 60.0:
            assert labels.code[lid] == (LEFT if own > 0 else RIGHT), (lid, own)
    assert set(labels.code) == set(by_id)


# --------------------------------------------------------------------------------------------
# robust reading
# --------------------------------------------------------------------------------------------
def test_broken_regulatory_element_is_logged_not_fatal(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    text = CROP.read_text()
    bad = ('<relation id="99999999" visible="true" version="1">'
           '<member type="way" ref="88888888" role="refers"/>'
           '<tag k="type" v="regulatory_element"/><tag k="subtype" v="traffic_sign"/>'
           '</relation>\n<relation id="99999998" visible="true" version="1">'
           '<member type="way" ref="88888887" role="outer"/>'
           '<tag k="type" v="multipolygon"/><tag k="subtype" v="parking"/></relation>\n</osm>')
    path = tmp_path / "map.osm"
    path.write_text(text.replace("</osm>", bad))
    with caplog.at_level(logging.WARNING):
        lmap = read_lanelet_map(path, CRS, site_frame())
    assert "99999999" in caplog.text or "99999998" in caplog.text
    assert len(lmap) == len(read_lanelet_map(CROP, CRS, site_frame()))


def test_broken_lanelet_is_skipped_while_the_map_has_drivable_ones(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A crosswalk relation with a misspelt member role: lanelet2 rejects it; the rest of the
    map is read (a map whose only lanelets are broken still fails, test_io)."""
    ref = read_lanelet_map(CROP, CRS, site_frame())
    victim = next(ll.id for ll in ref.ignored if ll.attributes.get("subtype") == "crosswalk")
    text = CROP.read_text()
    start = text.index(f'<relation id="{victim}"')
    end = text.index("</relation>", start)
    rel = text[start:end].replace('role="right"', 'role="rite"')
    path = tmp_path / "map.osm"
    path.write_text(text[:start] + rel + text[end:])
    with caplog.at_level(logging.WARNING):
        lmap = read_lanelet_map(path, CRS, site_frame())
    assert f"relation {victim} skipped (not drivable)" in caplog.text
    assert "while parsing" not in caplog.text     # lanelet2's header line is no error
    assert [ll.id for ll in lmap.lanelets] == [ll.id for ll in ref.lanelets]
    assert victim not in {ll.id for ll in lmap.ignored}
    assert len(lmap.ignored) == len(ref.ignored) - 1
    # a broken road lanelet is skipped too, but named in the map's warnings (the result's)
    road = ref.lanelets[0].id
    start = text.index(f'<relation id="{road}"')
    end = text.index("</relation>", start)
    path.write_text(text[:start] + text[start:end].replace('role="right"', 'role="rite"')
                    + text[end:])
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        lmap = read_lanelet_map(path, CRS, site_frame())
    assert f"relation {road} skipped (a road by its tags)" in caplog.text
    assert [ll.id for ll in lmap.lanelets] == [ll.id for ll in ref.lanelets[1:]]
    assert list(lmap.skipped) == [road] and "right border" in lmap.skipped[road]
    assert len(lmap.warnings()) == 1 and f"relation {road}" in lmap.warnings()[0]
    assert not ref.skipped and not ref.warnings()
    scn = flat_scenario(lmap, site_frame())
    assert any(f"relation {road}" in w for w in build_target_cloud(scn, MapConfig()).warnings)


def test_simulate_warns_once_of_a_broken_lanelet(tmp_path: Path,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    """The map simulator reads the map, then its crop: a relation lanelet2 rejects is named
    once, with the user's file, not again with the crop's temporary one."""
    from fgloc.sim.real_map import simulate_on_map

    ref = read_lanelet_map(CROP, CRS, site_frame())
    victim = next(ll.id for ll in ref.ignored if ll.attributes.get("subtype") == "crosswalk")
    text = CROP.read_text()
    start = text.index(f'<relation id="{victim}"')
    end = text.index("</relation>", start)
    path = tmp_path / "map.osm"
    path.write_text(text[:start] + text[start:end].replace('role="right"', 'role="rite"')
                    + text[end:])
    with caplog.at_level(logging.WARNING):
        simulate_on_map(path, 1, duration=2.0)
    named = [r.getMessage() for r in caplog.records if f"relation {victim} skipped" in
             r.getMessage()]
    assert len(named) == 1 and named[0].startswith(str(path))


def test_a_bound_drawn_as_several_ways_is_joined(tmp_path: Path) -> None:
    """INTERACTION and rounD maps draw a bound as several ways end to end, which lanelet2
    rejects ("not exactly one right border"). Split a road lanelet's right bound in two,
    listed in reverse order, the second piece reversed: the lanelet is read with the same
    bound as before."""
    ref = read_lanelet_map(CROP, CRS, site_frame())
    text = CROP.read_text()
    ll = max(ref.lanelets, key=lambda x: len(x.right))
    rel_start = text.index(f'<relation id="{ll.id}"')
    rel_end = text.index("</relation>", rel_start)
    rel = text[rel_start:rel_end]
    way_id = re.search(r'<member type="way" ref="(-?\d+)" role="right"', rel).group(1)
    w0 = text.index(f'<way id="{way_id}"')
    w1 = text.index("</way>", w0)
    refs = re.findall(r'<nd ref="(-?\d+)"', text[w0:w1])
    k = len(refs) // 2
    pieces = "".join(
        f'<way id="{wid}" visible="true" version="1">'
        + "".join(f'<nd ref="{r}"/>' for r in part)
        + '<tag k="type" v="line_thin"/><tag k="subtype" v="solid"/></way>\n'
        for wid, part in (("88888801", refs[:k + 1]), ("88888802", refs[k:][::-1])))
    rel = re.sub(rf'<member type="way" ref="{way_id}" role="right"\s*/>',
                 '<member type="way" ref="88888802" role="right"/>'
                 '<member type="way" ref="88888801" role="right"/>', rel)
    assert rel != text[rel_start:rel_end]
    text = text[:rel_start] + rel + text[rel_end:]
    path = tmp_path / "split.osm"
    path.write_text(text.replace("</osm>", pieces + "</osm>"))
    back = read_lanelet_map(path, CRS, site_frame())
    assert not back.skipped
    got = {x.id: x for x in back.lanelets}[ll.id]
    np.testing.assert_allclose(got.right, ll.right)
    np.testing.assert_allclose(got.left, ll.left)
    # a relation JOSM marks deleted is left alone, as lanelet2 leaves it
    from fgloc.io.lanelet_map import _join_split_bounds

    deleted = tmp_path / "deleted.osm"
    deleted.write_text(path.read_text().replace(f'<relation id="{ll.id}"',
                                                f'<relation id="{ll.id}" action="delete"'))
    assert _join_split_bounds(path, tmp_path / "a.osm") == [ll.id]
    assert _join_split_bounds(deleted, tmp_path / "b.osm") == []


def test_crop_keeps_the_regulatory_elements_its_lanelets_reference(tmp_path: Path) -> None:
    """A traffic light names only its ways (the light, the stop line); the lanelet it governs
    references it. The crop keeps it with that lanelet; one no lanelet references is dropped,
    and the crop reads back with the same drivable lanelets."""
    from fgloc.io.lanelet_map import crop_lanelet_osm

    ref = read_lanelet_map(CROP, CRS, site_frame())
    text = CROP.read_text()
    lid = ref.lanelets[0].id
    start = text.index(f'<relation id="{lid}"')
    cut = text.index("<tag", start)
    text = (text[:cut] + '<member type="relation" ref="99999990" role="regulatory_element"/>'
            + text[cut:])
    ways = re.findall(r'<way id="(\d+)"', text)[:2]
    lights = "".join(
        f'<relation id="{rid}" visible="true" version="1">'
        f'<member type="way" ref="{ways[0]}" role="refers"/>'
        f'<member type="way" ref="{ways[1]}" role="ref_line"/>'
        '<tag k="type" v="regulatory_element"/><tag k="subtype" v="traffic_light"/>'
        '</relation>\n' for rid in ("99999990", "99999991"))
    path = tmp_path / "map.osm"
    path.write_text(text.replace("</osm>", lights + "</osm>"))
    crop = crop_lanelet_osm(path, *SITE, 300.0)
    assert '<relation id="99999990"' in crop and '<relation id="99999991"' not in crop
    (tmp_path / "crop.osm").write_text(crop)
    back = read_lanelet_map(tmp_path / "crop.osm", CRS, site_frame())
    assert [ll.id for ll in back.lanelets] == [ll.id for ll in ref.lanelets]


def test_lanelet_referencing_an_unknown_regulatory_element_is_read(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Autoware maps tie lanelets to regulatory elements lanelet2 does not implement
    (detection_area, no_stopping_area, ...): lanelet2 then rejects the lanelet itself. fgloc
    reads it without that reference (one to a relation the map lacks lanelet2 only logs)."""
    ref = read_lanelet_map(CROP, CRS, site_frame())
    text = CROP.read_text()
    roads = [ll.id for ll in ref.lanelets[:2]]
    for lid, reg in zip(roads, ("99999990", "99999991")):   # the second one is missing
        start = text.index(f'<relation id="{lid}"')
        cut = text.index("<tag", start)
        text = (text[:cut] + f'<member type="relation" ref="{reg}" role="regulatory_element"/>'
                + text[cut:])
    way = re.search(r'<way id="(\d+)"', text).group(1)
    text = text.replace("</osm>", '<relation id="99999990" visible="true" version="1">'
                        f'<member type="way" ref="{way}" role="refers"/>'
                        '<tag k="type" v="regulatory_element"/>'
                        '<tag k="subtype" v="detection_area"/></relation>\n</osm>')
    path = tmp_path / "map.osm"
    path.write_text(text)
    raw, errors = lanelet2.io.loadRobust(str(path), UtmProjector(Origin(*SITE)))
    assert any(f"primitive {roads[0]}" in e for e in errors)   # lanelet2 alone rejects it
    with caplog.at_level(logging.WARNING):
        got = read_lanelet_map(path, CRS, site_frame())
    assert f"relation {roads[0]} read without its reference(s) to relation 99999990" \
        in caplog.text
    assert "99999991" in caplog.text            # lanelet2 itself reads past a missing one
    assert [ll.id for ll in got.lanelets] == [ll.id for ll in ref.lanelets]
    assert not got.skipped and got.successors == ref.successors
    assert max(np.abs(a.left - b.left).max() for a, b in zip(got.lanelets, ref.lanelets)) < 1e-9


def test_nodes_without_ele_take_the_als_ground(crop_map: LaneletMap) -> None:
    frame = site_frame(100.0)
    grad = np.array([0.02, -0.01])
    rng = np.random.default_rng(3)
    xy = rng.uniform(-150, 150, (200_000, 2))
    z = 1.5 + xy @ grad + rng.normal(0, 0.02, len(xy))
    cls = np.where(rng.random(len(xy)) < 0.1, 6, 2).astype(np.uint8)  # roofs are not ground
    z[cls == 6] += 12.0
    als = AlsCloud(np.column_stack([xy, z]).astype(np.float32), cls)
    lmap = read_lanelet_map(CROP, CRS, frame, ground=als_ground(als))
    pts = np.vstack([np.vstack([ll.left, ll.right]) for ll in lmap.lanelets])
    near = np.abs(pts[:, :2]).max(axis=1) < 140
    err = pts[near, 2] - (1.5 + pts[near, :2] @ grad)
    assert np.abs(err).max() < 0.1
    # without a ground the height is 0 in L (the old behaviour, still used in memory)
    flat = read_lanelet_map(CROP, CRS, frame)
    assert np.all(flat.lanelets[0].left[:, 2] == 0.0)


def test_ele_tags_win_over_the_ground(tmp_path: Path) -> None:
    text = CROP.read_text()
    node_id = next(iter(lanelet2.io.load(str(CROP), UtmProjector(Origin(*SITE))).laneletLayer)
                   ).leftBound[0].id
    first = re.search(rf'<node id="{node_id}"[^>]*?(/>)', text)
    assert first is not None
    patched = text[: first.start(1)] + '><tag k="ele" v="123.25"/></node>' + text[first.end(1):]
    path = tmp_path / "map.osm"
    path.write_text(patched)
    frame = site_frame(100.0)
    lmap = read_lanelet_map(path, CRS, frame, ground=lambda xy: np.full(len(xy), -7.0))
    ll2 = lanelet2.io.load(str(path), UtmProjector(Origin(*SITE)))
    heights = {}
    for ll in ll2.laneletLayer:
        for b_ll2, b in ((ll.leftBound, "left"), (ll.rightBound, "right")):
            ours = getattr(next(x for x in lmap.lanelets + lmap.ignored if x.id == ll.id), b)
            heights.update({pt.id: z for pt, z in zip(b_ll2, ours[:, 2])})
    tagged = {int(i): float(v) for i, v in
              re.findall(r'<node id="(\d+)"[^>]*>\s*<tag k="ele" v="([^"]+)"', patched)}
    assert tagged[node_id] == 123.25 and len(tagged) >= 2  # the crop's own ele = 3 nodes too
    for i, z in heights.items():
        assert z == pytest.approx(tagged[i] - 100.0 if i in tagged else -7.0)


@pytest.mark.parametrize("local_crs,latlon", [("EPSG:25832", ' lat="0" lon="0"'),
                                               ("EPSG:3035", ' lat="0" lon="0"'),
                                               ("EPSG:25832", ' lat="" lon=""'),
                                               ("EPSG:25832", "")])
def test_local_xy_nodes_with_declared_crs_and_offset(tmp_path: Path, local_crs: str,
                                                     latlon: str) -> None:
    """Autoware-style nodes: local_x/local_y in a declared CRS relative to an offset, lat/lon
    0, empty (as Vector Map Builder exports them) or absent. They must land where the lat/lon
    of the original map put them (< 1 mm)."""
    text = CROP.read_text()
    offset = (4_210_000.0, 2_860_000.0) if local_crs == "EPSG:3035" else (456_000.0, 5_429_000.0)
    to_local = transformer("EPSG:4326", local_crs)

    def repl(m: re.Match[str]) -> str:
        lat, lon = float(m.group(2)), float(m.group(3))
        x, y = to_local.transform(lon, lat)
        return (f'<node id="{m.group(1)}"{latlon}><tag k="local_x" '
                f'v="{x - offset[0]:.5f}"/><tag k="local_y" v="{y - offset[1]:.5f}"/>'
                f"{m.group(4)}")
    pattern = r'<node id="(\d+)" visible="true" version="1" lat="([-\d.]+)" lon="([-\d.]+)"' \
              r'\s*(/>|>)'
    local_text, n = re.subn(pattern, repl, text)
    assert n > 100
    local_text = local_text.replace('"/>/>', '"/></node>')
    path = tmp_path / "map.osm"
    path.write_text(local_text)
    frame = site_frame()
    ref = read_lanelet_map(CROP, CRS, frame)
    with pytest.raises(InputError, match="local_crs"):
        read_lanelet_map(path, CRS, frame)
    got = read_lanelet_map(path, CRS, frame,
                           settings=MapSettings(local_crs=local_crs, local_offset=offset))
    assert [ll.id for ll in got.lanelets] == [ll.id for ll in ref.lanelets]
    err = max(np.abs(a.left - b.left).max() for a, b in zip(got.lanelets, ref.lanelets))
    assert err < 1e-3


def test_local_xy_nodes_far_from_the_prime_meridian(tmp_path: Path) -> None:
    """Vector Map Builder nodes (empty lat/lon) of a map in Japan (UTM zone 54): the crop's
    geometry moved there, local_x/local_y in EPSG:32654. Every node, lanelet and successor is
    read as in Germany (lanelet2's projector must take its origin from the declared
    coordinates, not from the empty lat/lon: zone 31 is over 130 deg away)."""
    frame = site_frame()
    ref = read_lanelet_map(CROP, CRS, frame)
    to_utm = transformer("EPSG:4326", CRS)

    def repl(m: re.Match[str]) -> str:
        e, n = to_utm.transform(float(m.group(3)), float(m.group(2)))
        return (f'<node id="{m.group(1)}" lat="" lon=""><tag k="local_x" '
                f'v="{e - frame.origin[0]:.5f}"/><tag k="local_y" v="{n - frame.origin[1]:.5f}"/>'
                f"{m.group(4)}")
    pattern = r'<node id="(\d+)" visible="true" version="1" lat="([-\d.]+)" lon="([-\d.]+)"' \
              r'\s*(/>|>)'
    text, n = re.subn(pattern, repl, CROP.read_text())
    assert n > 100
    path = tmp_path / "japan.osm"
    path.write_text(text.replace('"/>/>', '"/></node>'))
    origin = (400_000.0, 3_900_000.0)
    got = read_lanelet_map(path, "EPSG:32654", LocalFrame(origin + (0.0,), "EPSG:32654"),
                           settings=MapSettings(local_crs="EPSG:32654", local_offset=origin))
    assert [ll.id for ll in got.lanelets] == [ll.id for ll in ref.lanelets]
    assert len(got.ignored) == len(ref.ignored) and got.successors == ref.successors
    assert max(np.abs(a.left - b.left).max() for a, b in zip(got.lanelets, ref.lanelets)) < 1e-3


def test_vector_map_builder_nodes_with_lat_lon_need_no_declaration(tmp_path: Path) -> None:
    """Vector Map Builder / Autoware maps of real streets carry lat/lon next to their
    ``mgrs_code`` / ``local_x`` / ``local_y`` / ``ele`` tags: without a declared ``local_crs``
    the lat/lon place the nodes, whatever the local tags say."""
    text = CROP.read_text()

    def repl(m: re.Match[str]) -> str:
        extra = ('<tag k="mgrs_code" v="32UMV560290"/><tag k="local_x" v="12.5"/>'
                 '<tag k="local_y" v="-7.25"/>')
        return f"{m.group(1)}>{extra}" + ("</node>" if m.group(2) == "/>" else "")
    vmb, n = re.subn(r'(<node id="\d+" visible="true" version="1" lat="[-\d.]+" '
                     r'lon="[-\d.]+")\s*(/>|>)', repl, text)
    assert n > 100
    path = tmp_path / "map.osm"
    path.write_text(vmb)
    frame = site_frame()
    ref = read_lanelet_map(CROP, CRS, frame)
    got = read_lanelet_map(path, CRS, frame)
    assert [ll.id for ll in got.lanelets] == [ll.id for ll in ref.lanelets]
    assert max(np.abs(a.left - b.left).max() for a, b in zip(got.lanelets, ref.lanelets)) < 1e-6


def test_sensor_toml_map_table_round_trip(tmp_path: Path) -> None:
    cfg = SensorConfig(approx_position=(456000.0, 5429000.0), crs=CRS,
                       map=MapSettings("de", "vehicle:truck", "EPSG:31467", (3.4e6, 5.4e6)))
    write_sensor_toml(tmp_path / "sensor.toml", cfg)
    assert read_sensor_toml(tmp_path / "sensor.toml") == cfg
    plain = SensorConfig(approx_position=(456000.0, 5429000.0))
    write_sensor_toml(tmp_path / "plain.toml", plain)
    assert "[map]" not in (tmp_path / "plain.toml").read_text()
    assert read_sensor_toml(tmp_path / "plain.toml").map == MapSettings()
    (tmp_path / "bad.toml").write_text(
        '[sensor]\napprox_position = [1.0, 2.0]\n[map]\nlocal_crs = "EPSG:4326"\n')
    with pytest.raises(InputError, match="map.local_crs"):
        read_sensor_toml(tmp_path / "bad.toml")


INVERTED = """<?xml version="1.0"?>
<osm version="0.6">
  <node id="1" lat="49.0" lon="8.4"/><node id="2" lat="49.0" lon="8.4005"/>
  <node id="3" lat="49.00003" lon="8.4"/><node id="4" lat="49.00003" lon="8.4005"/>
  <node id="5" lat="49.00006" lon="8.4"/><node id="6" lat="49.00006" lon="8.4005"/>
  <way id="10"><nd ref="1"/><nd ref="2"/></way>
  <way id="11"><nd ref="3"/><nd ref="4"/></way>
  <way id="12"><nd ref="6"/><nd ref="5"/></way>
  <relation id="20"><member type="way" ref="11" role="left"/>
    <member type="way" ref="10" role="right"/>
    <tag k="type" v="lanelet"/><tag k="subtype" v="road"/></relation>
  <relation id="21"><member type="way" ref="11" role="left"/>
    <member type="way" ref="12" role="right"/>
    <tag k="type" v="lanelet"/><tag k="subtype" v="road"/></relation>
</osm>
"""


def test_a_road_site_without_mast_place_is_drawn_again(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A random road site with no mast place (a stub of road) is not the end: another random
    metre of road is tried (up to ROAD_SITE_ATTEMPTS); a --site that has none is an error."""
    import fgloc.sim.real_map as real_map

    path = tmp_path / "map.osm"
    path.write_text(INVERTED)
    place, calls = real_map._place_mast, []

    def fails_first(*args: object, **kwargs: object) -> object:
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("no roadside position for the sensor")
        return place(*args, **kwargs)

    monkeypatch.setattr(real_map, "_place_mast", fails_first)
    sim = real_map.simulate_on_map(path, 1, duration=2.0)
    assert sim.site == "road" and len(calls) == 2
    calls.clear()
    with pytest.raises(RuntimeError, match="no roadside position"):
        real_map.simulate_on_map(path, 1, duration=2.0, site=(49.00003, 8.40025))
    assert len(calls) == 1


def test_inverted_shared_bound(tmp_path: Path) -> None:
    """Two opposite lanes share their middle line (way 11, drawn eastwards): the westbound
    lanelet 21 uses it inverted, and its right bound (way 12) runs westwards."""
    path = tmp_path / "map.osm"
    path.write_text(INVERTED)
    e, n = transformer("EPSG:4326", CRS).transform(8.4, 49.0)
    lmap = read_lanelet_map(path, CRS, LocalFrame.around(e, n, 0.0, CRS))
    by_id = {ll.id: ll for ll in lmap.lanelets}
    assert set(by_id) == {20, 21}
    for lid, direction in ((20, 1.0), (21, -1.0)):
        ll = by_id[lid]
        for bound in (ll.left, ll.right):
            assert np.sign(bound[-1, 0] - bound[0, 0]) == direction
        # left of the driving direction: north for eastbound, south for westbound
        assert np.sign(ll.left[:, 1].mean() - ll.right[:, 1].mean()) == direction
    np.testing.assert_allclose(by_id[21].left, by_id[20].left[::-1])


def test_simulate_on_a_map_without_junction_watches_a_road(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two opposite lanes and nothing else (36 m): no junction, so the mast stands beside the
    road; vehicles drive both lanes, each in its own direction. A --site 10 km away is an error
    that says so, and nothing is written."""
    from fgloc.cli import main
    from fgloc.sim.real_map import simulate_on_map

    path = tmp_path / "map.osm"
    path.write_text(INVERTED)
    sim = simulate_on_map(path, 1, duration=10.0)
    assert "the original map's copyright and licence apply" in sim.map_osm   # no LICENSE here
    assert sim.site == "road" and len(sim.scenario.truth.tracks) >= 2
    lanes = {ll.id: ll for ll in sim.scenario.lanelets.lanelets}
    heads = []
    for tr in sim.scenario.truth.tracks:
        st = np.asarray(tr.states)
        heads.append(np.cos(st[:, 3]).mean())
        # on the lanelet of its direction: eastbound on 20 (south lane), westbound on 21
        lane = lanes[20 if heads[-1] > 0 else 21]
        inside = points_in_polygon(st[:, 1:3], lane.polygon(), 0.5)
        lo, hi = np.sort(lane.left[[0, -1], 0])
        assert inside[(st[:, 1] > lo + 3.0) & (st[:, 1] < hi - 3.0)].mean() > 0.9
    assert min(heads) < -0.9 and max(heads) > 0.9
    assert main(["simulate", "--map", str(path), "--seed", "2", "--duration", "5", "--out",
                 str(tmp_path / "scn")]) == 0
    assert "(road at E" in capsys.readouterr().out
    assert main(["simulate", "--map", str(path), "--site", "49.1,8.4", "--out",
                 str(tmp_path / "far")]) == 2
    assert "no junction of the routing graph and no drivable lanelet within 500 m" in \
        capsys.readouterr().err
    assert not (tmp_path / "far").exists()


# --------------------------------------------------------------------------------------------
# simulate --map
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def crop_sim(tmp_path_factory: pytest.TempPathFactory):
    from fgloc.io import load_scenario, write_scenario
    from fgloc.sim.real_map import simulate_on_map

    sim = simulate_on_map(CROP, 4, duration=10.0, crop_radius=150.0)
    out = tmp_path_factory.mktemp("sim") / "scn"
    write_scenario(sim.scenario, out, map_osm=sim.map_osm, extra_files=sim.notices)
    return sim, out, load_scenario(out)


def test_simulated_scenario_keeps_the_contract_and_the_real_map(crop_sim) -> None:
    sim, out, loaded = crop_sim
    assert "see the LICENSE files beside this map" in sim.map_osm
    assert (out / "LICENSE-lanelet2_mapping_example").read_text() == (
        DATA / "LICENSE-lanelet2_mapping_example").read_text()
    text = (out / "map.osm").read_text()
    # the crop names its source and points to the licence beside it; heights come from the ALS
    assert f"Crop of {CROP.name}" in text and "LICENSE" in text and 'k="ele"' not in text
    assert {ll.id for ll in loaded.lanelets.lanelets} <= {ll.id for ll in read_lanelet_map(
        CROP, CRS, site_frame()).lanelets}
    assert loaded.lanelets.ignored_by_kind() == sim.scenario.lanelets.ignored_by_kind()
    assert loaded.truth is not None and len(loaded.truth.tracks) >= 3
    np.testing.assert_allclose(loaded.truth.sensor_pose, sim.scenario.truth.sensor_pose,
                               atol=1e-3)
    # nodes without ele took the simulated ALS ground: within the road raise and noise
    for a, b in zip(loaded.lanelets.lanelets, sim.scenario.lanelets.lanelets):
        near = np.abs(a.left[:, :2] - loaded.truth.sensor_pose[:2, 3]).max(axis=1) < 150
        assert np.abs(a.left[near, 2] - b.left[near, 2]).max(initial=0.0) < 0.25


def test_simulated_vehicles_drive_on_drivable_lanelets(crop_sim) -> None:
    sim, _, scn = crop_sim
    centres = np.vstack([t.states[:, 1:3] for t in scn.truth.tracks])
    on_road = inside_any(centres, scn.lanelets.lanelets, margin=0.3)
    assert on_road.mean() > 0.99
    mast = scn.truth.sensor_pose[:2, 3]
    assert not inside_any(mast[None], scn.lanelets.lanelets, margin=0.5)[0]
    assert 15.0 < np.linalg.norm(mast - sim.junction) < 45.0
    # road-surface ALS points lie in drivable lanelets only; roofs in the map's buildings
    xy = scn.als.xyz[:, :2].astype(float)
    road = scn.als.classification == 11
    assert road.sum() > 1000 and inside_any(xy[road], scn.lanelets.lanelets).all()
    walls = [a.outline for a in scn.lanelets.areas if a.subtype == "building"]
    roof = scn.als.classification == 6
    assert roof.any() and all(
        np.any([points_in_polygon(xy[roof][k:k + 1], w)[0] for w in walls])
        for k in range(0, int(roof.sum()), max(1, int(roof.sum()) // 50)))


def test_simulate_on_map_is_deterministic_and_site_picks_the_junction() -> None:
    from fgloc.sim.real_map import map_junctions, simulate_on_map

    junctions, _ = map_junctions(CROP)
    assert len(junctions) >= 2
    far = junctions[-1].centre
    a = simulate_on_map(CROP, 2, duration=2.0, site=(float(far[0]), float(far[1])))
    b = simulate_on_map(CROP, 2, duration=2.0, site=(float(far[0]), float(far[1])))
    np.testing.assert_array_equal(a.scenario.radar.xyz, b.scenario.radar.xyz)
    w = a.scenario.frame.to_world(a.junction[None])[0]
    lon, lat = transformer(CRS, "EPSG:4326").transform(w[0], w[1])
    assert np.hypot((lat - far[0]) * 111e3, (lon - far[1]) * 73e3) < 5.0


@pytest.mark.parametrize("seed", [1, 2])
def test_mast_at_an_edge_junction_watches_the_mapped_road(seed: int) -> None:
    """At a junction on the crop's edge a mast looking at the junction from the wrong side
    sees little mapped road (the first placement found saw 128-209 m of lane centre line
    there); the simulator aims it where the map has road: >= 900 m of drivable lanelet centre
    line within 150 m and the 120 deg field of view, the junction inside it."""
    from fgloc.sim.real_map import simulate_on_map

    for site in ((49.00506952803902, 8.416545740174582), (49.00477629793021, 8.415454226165508)):
        sim = simulate_on_map(CROP, seed, duration=1.0, site=site)
        T = sim.scenario.truth.sensor_pose
        yaw = np.arctan2(T[1, 0], T[0, 0])
        centre = [resample_polyline(c, max(2, int(np.linalg.norm(np.diff(c, axis=0),
                                                                 axis=1).sum()) + 1))
                  for c in (ll.centerline(50) for ll in sim.scenario.lanelets.lanelets)]
        rel = np.vstack([*centre, sim.junction[None]]) - T[:2, 3]
        seen = (np.hypot(rel[:, 0], rel[:, 1]) <= 150.0) & (
            np.abs(wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - yaw)) <= np.deg2rad(60.0))
        assert seen[-1], "the junction is outside the field of view"
        assert seen[:-1].sum() >= 900, f"{site}: only {seen[:-1].sum()} m of mapped road seen"


def test_radar_turns_from_the_junction_only_towards_much_more_road() -> None:
    """A junction straight ahead (bearing 0) with 11 m of road there and 91 m running out at
    bearing 70 deg: aiming at the junction sees the 11 m (the 70 deg road is outside the
    +-60 deg view), turning by 10 deg or more sees all 102 m, so the radar turns by the least
    such angle and the junction stays inside the view. With road enough ahead it does not."""
    from fgloc.sim import SimConfig
    from fgloc.sim.real_map import JUNCTION_IN_VIEW_MARGIN_DEG, _aim

    cfg = SimConfig()
    assert cfg.radar.hfov_deg == 120.0

    def ray(bearing_deg: float, r0: float, r1: float) -> np.ndarray:
        r = np.arange(r0, r1 + 0.5)
        return r[:, None] * np.array([np.cos(np.deg2rad(bearing_deg)),
                                      np.sin(np.deg2rad(bearing_deg))])

    road = np.vstack([ray(0.0, 20.0, 30.0), ray(70.0, 10.0, 100.0)])
    yaw, seen = _aim(np.zeros(2), 0.0, road, cfg)
    assert seen == len(road) == 102
    assert np.rad2deg(yaw) == pytest.approx(10.0)
    assert 60.0 - abs(np.rad2deg(yaw)) >= JUNCTION_IN_VIEW_MARGIN_DEG
    # 61 m ahead: turning would see 102 m, less than twice that: the radar keeps its aim
    yaw, seen = _aim(np.zeros(2), 0.0, np.vstack([ray(0.0, 20.0, 80.0), ray(70.0, 10.0, 50.0)]),
                     cfg)
    assert yaw == 0.0 and seen == 61


def test_a_bound_that_runs_on_past_the_other_is_named(crop_map: LaneletMap) -> None:
    """A lanelet's ends are lines across the road: the crop's flared junction turns end at
    most a few lanes apart, while a lanelet whose right bound runs 100 m past its left one
    (as one of the example map's does) is named by ``fgloc info`` and, near the sensor, in
    the localization's warnings."""
    from fgloc.map.target_cloud import ragged_warning
    from fgloc.scenario import RAGGED_END_GAP, ragged

    gaps = [ll.end_gap() for ll in crop_map.lanelets]
    assert max(gaps) < RAGGED_END_GAP and not ragged(crop_map.lanelets)
    z = np.zeros((3, 1))
    left = np.hstack([[[0.0, 3.5], [12.0, 3.5], [25.0, 3.5]], z])
    right = np.hstack([[[0.0, 0.0], [25.0, 0.0], [125.0, -2.0]], z])
    bad = Lanelet(7, left, right, {"subtype": "road"})
    assert bad.end_gap() == pytest.approx(np.hypot(100.0, 5.5))
    assert ragged([*crop_map.lanelets, bad]) == [7]
    (warning,) = ragged_warning([bad])
    assert "relation 7" in warning and "30 m" in warning
    assert ragged_warning(crop_map.lanelets) == []


def test_cli_simulate_map_and_info(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from fgloc.cli import main

    out = tmp_path / "scn"
    assert main(["simulate", "--map", str(CROP), "--seed", "3", "--duration", "3",
                 "--out", str(out)]) == 0
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert re.search(r"lanelets\s+\d+ drivable \(road \d+; lanelet2 traffic rules de/vehicle\)",
                     text)
    assert "crosswalk" in text and "not drivable" in text and "from the routing graph" in text
    # the crop's hand-mapped turns: the two centre-line constructions apart by up to ~1 m
    m = re.search(r"centre line 'mean'; .* median ([\d.]+) m, max ([\d.]+) m, over 0.3 m on "
                  r"(\d+) lanelets", text)
    assert m and float(m[1]) < 0.2 and 0.3 < float(m[2]) < 2.5 and int(m[3]) >= 1, text
    assert re.search(r"skipped\s+0 roads lanelet2 rejected\n", text)
    assert re.search(r"ragged\s+0 drivable with bounds ending more than 30 m apart\n", text)
    # a road lanelet lanelet2 rejects (its right bound's role misspelt) is named
    osm = (out / "map.osm").read_text()
    road = next(r for r in re.finditer(r'<relation id="(-?\d+)".*?</relation>', osm, re.S)
                if 'v="road"' in r[0] and 'role="right"' in r[0])
    (out / "map.osm").write_text(osm[:road.start()] + road[0].replace('role="right"', 'role="x"')
                                 + osm[road.end():])
    assert main(["info", str(out)]) == 0
    assert f"skipped     1 roads lanelet2 rejected (relation {road[1]})" in capsys.readouterr().out
    assert main(["simulate", "--map", str(CROP), "--site", "49.0", "--out",
                 str(tmp_path / "x")]) == 2
    assert main(["simulate", "--map", str(CROP), "--site", "49.1,8.4", "--out",
                 str(tmp_path / "far")]) == 2  # 10 km from every junction
    assert "no junction of the routing graph and no drivable lanelet within 500 m" in \
        capsys.readouterr().err
    assert main(["simulate", "--case", "straight", "--site", "49.0,8.4", "--out",
                 str(tmp_path / "y")]) == 2


def test_every_method_on_the_crop_junction(crop_sim) -> None:
    """Every method localizes the simulated crop junction (60 s of traffic)."""
    from fgloc.evaluation.pose import pose_error
    from fgloc.pipeline import localize_many
    from fgloc.sim.real_map import simulate_on_map

    scn = simulate_on_map(CROP, 1, duration=60.0, crop_radius=150.0).scenario
    res = localize_many(scn, ["icp", "filter-sicp", "smoother-sicp", "joint"])
    for method, r in res.items():
        e = pose_error(r.T_local, scn.truth.sensor_pose)
        assert r.converged, method
        # measured (seed 1): icp 0.10 m / 0.10 deg, filter-sicp 0.26 / 0.35, smoother-sicp
        # 0.20 / 0.34, joint 0.14 / 0.06
        bound = (0.25, 0.2) if method == "joint" else (0.5, 0.5)
        assert e.d2d < bound[0] and e.dyaw_deg < bound[1], (method, e)


def test_simulate_on_a_map_in_another_utm_zone(tmp_path: Path) -> None:
    """The crop moved 6 deg east (UTM zone 33): the world CRS follows the map."""
    from fgloc.io import load_scenario, write_scenario
    from fgloc.sim.real_map import simulate_on_map

    text = re.sub(r'lon="([-\d.]+)"', lambda m: f'lon="{float(m.group(1)) + 6.0:.11f}"',
                  CROP.read_text())
    path = tmp_path / "east.osm"
    path.write_text(text)
    sim = simulate_on_map(path, 1, duration=2.0)
    assert sim.scenario.crs == "EPSG:32633"
    write_scenario(sim.scenario, tmp_path / "scn", map_osm=sim.map_osm)
    loaded = load_scenario(tmp_path / "scn")
    assert loaded.crs == "EPSG:32633" and len(loaded.lanelets) == len(sim.scenario.lanelets)


def test_path_labels_follow_the_turns_and_the_kinks_of_the_crop(crop_sim) -> None:
    """``[map] lane_labels = "path"`` on the example map's crop: the lanelets whose own centre
    line turns by more than 45 deg keep their turn's label on at least 80 % of their samples;
    long lanelets that turn by less than 3 deg stay straight on at least three quarters (their
    ends bend into the next lanelet; 0.77 the least at writing); and chains of
    short lanelets bent only at their joins (own turn under 1 deg, labelled straight by the
    lanelet rules) turn somewhere, as the vehicles driving them do."""
    from fgloc.coarse import LaneCentres
    from fgloc.config import MapConfig
    from fgloc.labels import LEFT, RIGHT, STRAIGHT
    from fgloc.map.target_cloud import build_target_cloud
    from fgloc.registration.fine import lane_labels

    scn = crop_sim[2]
    cfg = MapConfig()
    target = build_target_cloud(scn, cfg)
    lanelets = target.lanelets(scn.lanelets)
    lanes = LaneCentres.of_target(target, scn.lanelets, 0.25, cfg.two_way_min_width,
                                  cfg.centre_line)
    by_lanelet = lane_labels(target, lanelets, lanes)
    by_path = lane_labels(target, lanelets, lanes, MapConfig(lane_labels="path"), scn.lanelets)
    turns, straights, kinked = 0, 0, 0
    for k, ll in enumerate(lanelets):
        sel = (lanes.lanelet == k) & ~lanes.against
        if not sel.any():
            continue
        c = ll.centerline(20)
        h = np.arctan2(np.diff(c[:, 1]), np.diff(c[:, 0]))
        turn = float(np.degrees(np.angle(np.exp(1j * (h[-1] - h[0])))))
        share = np.bincount(by_path[sel], minlength=3) / sel.sum()
        if abs(turn) > 45.0:
            assert share[LEFT if turn > 0 else RIGHT] >= 0.8, (ll.id, turn, share)
            turns += 1
        elif abs(turn) < 3.0 and sel.sum() >= 100:
            assert share[STRAIGHT] >= 0.75, (ll.id, turn, share)
            straights += 1
        if abs(turn) < 1.0 and np.all(by_lanelet[sel] == STRAIGHT) and share[STRAIGHT] < 0.5:
            kinked += 1
    assert turns >= 4 and straights >= 8 and kinked >= 5
