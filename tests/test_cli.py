"""The command line end to end on a short simulated scenario: exit codes, outputs, errors."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from fgloc.cli import main


@pytest.fixture(scope="module")
def scenario_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "tj"
    assert (
        main(
            [
                "-q",
                "simulate",
                "--case",
                "tjunction",
                "--seed",
                "4",
                "--duration",
                "40",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return out


def test_info_valid(scenario_dir, capsys):
    assert main(["-q", "info", str(scenario_dir)]) == 0
    text = capsys.readouterr().out
    assert "EPSG:25832" in text and "lanelets" in text and "detections" in text


def test_info_corrupted_radar_exit_2(scenario_dir, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(scenario_dir, bad)
    lines = (bad / "radar.csv").read_text().splitlines()
    cols = lines[5].split(",")
    cols[1] = "nan"
    lines[5] = ",".join(cols)
    (bad / "radar.csv").write_text("\n".join(lines) + "\n")
    assert main(["-q", "info", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "radar.csv" in err and "row 6" in err


def test_info_missing_map_exit_2(scenario_dir, tmp_path, capsys):
    bad = tmp_path / "nomap"
    shutil.copytree(scenario_dir, bad)
    (bad / "map.osm").unlink()
    assert main(["-q", "info", str(bad)]) == 2
    assert "map.osm" in capsys.readouterr().err


def test_localize_icp_and_evaluate(scenario_dir, tmp_path, capsys):
    out = tmp_path / "res"
    assert main(["-q", "localize", str(scenario_dir), "--out", str(out), "--method", "icp"]) == 0
    for name in ("result.json", "target.ply", "source.ply", "sensor.geojson", "overview.png"):
        assert (out / name).stat().st_size > 0, name
    doc = json.loads((out / "result.json").read_text())
    assert doc["method"] == "icp" and np.asarray(doc["T_utm"]).shape == (4, 4)
    assert 47.0 < doc["lat"] < 50.0 and 10.0 < doc["lon"] < 13.0
    capsys.readouterr()
    gt = scenario_dir / "ground_truth.json"
    assert main(["evaluate", str(out / "result.json"), str(gt), "--json"]) == 0
    evaluated = json.loads(capsys.readouterr().out)
    assert evaluated["status"] == doc["status"] and evaluated["method"] == "icp"
    err = evaluated["pose"]
    assert err["d2d"] < 1.5 and err["dyaw_deg"] < 1.5
    # the tilt's std. devs. are reported and cover its error
    assert 0.0 < doc["pitch_std_deg"] < 2.0 and 0.0 < doc["roll_std_deg"] < 2.0
    assert abs(err["dpitch_deg"]) < 3.0 * doc["pitch_std_deg"]
    assert abs(err["droll_deg"]) < 3.0 * doc["roll_std_deg"]
    geo = json.loads((out / "sensor.geojson").read_text())
    assert [f["geometry"]["type"] for f in geo["features"]] == ["Point", "Polygon"]


def test_localize_too_few_dynamic_points_writes_nothing(scenario_dir, tmp_path, capsys):
    cfg = tmp_path / "strict.toml"
    cfg.write_text("[coarse]\ndoppler_min = 500.0\n")  # no detection moves this fast
    out = tmp_path / "never"
    rc = main(["-q", "localize", str(scenario_dir), "--out", str(out), "--config", str(cfg)])
    assert rc == 2
    assert "dynamic" in capsys.readouterr().err
    assert not out.exists()


def _first_seconds(scenario: Path, seconds: float, out: Path) -> Path:
    """A copy of the scenario directory with only the radar rows of its first ``seconds``."""
    shutil.copytree(scenario, out)
    lines = (scenario / "radar.csv").read_text().splitlines()
    t0 = float(lines[1].split(",")[0])
    kept = [row for row in lines[1:] if float(row.split(",")[0]) < t0 + seconds]
    (out / "radar.csv").write_text("\n".join([lines[0], *kept]) + "\n")
    return out


def test_localize_without_vehicle_tracks_exits_2_and_writes_nothing(scenario_dir, tmp_path,
                                                                     capsys):
    """Every track slower than the walking bound: filter-sicp has no vehicle to register and
    says why (exit 2, nothing written), the joint says its start failed; icp needs no
    tracks. On the scenario's first 12 s (its tracks are born within them)."""
    scenario_dir = _first_seconds(scenario_dir, 12.0, tmp_path / "short")
    cfg = tmp_path / "walk.toml"
    cfg.write_text("[tracking]\nwalking_speed = 100.0\n")
    out = tmp_path / "never"
    rc = main(["-q", "localize", str(scenario_dir), "--method", "filter-sicp", "--out",
               str(out), "--config", str(cfg)])
    err = capsys.readouterr().err
    assert rc == 2 and not out.exists()
    assert "no vehicle track to register" in err and "smaller or slower" in err
    rc = main(["-q", "localize", str(scenario_dir), "--method", "joint", "--out", str(out),
               "--config", str(cfg)])
    err = capsys.readouterr().err
    assert rc == 2 and not out.exists()
    assert "joint starts from filter-sicp's result, which failed" in err
    assert main(["-q", "localize", str(scenario_dir), "--method", "icp", "--out",
                 str(tmp_path / "icp"), "--config", str(cfg)]) == 0


def test_config_dump_round_trips(tmp_path, capsys):
    assert main(["config", "--dump"]) == 0
    p = tmp_path / "c.toml"
    p.write_text(capsys.readouterr().out)
    assert main(["config", "--config", str(p)]) == 0


def test_track_oracle_and_evaluate_tracks(scenario_dir, tmp_path, capsys):
    out = tmp_path / "trk"
    assert main(["-q", "track", str(scenario_dir), "--out", str(out), "--oracle-pose"]) == 0
    header = (out / "tracks.csv").read_text().splitlines()[0].split(",")
    assert header[:9] == ["track_id", "t", "x", "y", "v", "a", "yaw", "yawrate", "label"]
    assert header[9:] == [f"r{i}" for i in range(20)]
    printed = capsys.readouterr().out
    n_tracks = len({row.split(",")[0] for row in
                    (out / "tracks.csv").read_text().splitlines()[1:]})
    assert re.search(rf"^{n_tracks} tracks \(\d+ joined to a lost track\)", printed, re.M)
    assert re.search(r"; \d+ tracks of other road users left out \(\d+ smaller or slower "
                     r"than a motor vehicle, \d+ off the drivable lanelets", printed, re.M)
    gt = scenario_dir / "ground_truth.json"
    assert main(["evaluate", str(out), str(gt), "--json"]) == 0
    tracking = json.loads(capsys.readouterr().out)["tracking"]
    # the tracker finds most vehicles that stay >= 2 s in view, with sane errors
    assert tracking["tracked_share"] >= 0.6
    assert tracking["yaw_error_deg"] < 10.0 and tracking["iou"] > 0.3


def test_evaluate_tracks_counts_no_vehicle_hidden_behind_a_building(scenario_dir, tmp_path,
                                                                     capsys):
    """A 40 m high building ring 10-11 m around the mast hides every vehicle: `fgloc evaluate`
    reads the scenario's ALS beside the ground truth and counts none of them as eligible
    (missed), where the field of view alone counts them all."""
    from fgloc.io import load_scenario
    from fgloc.io.als import find_als_tiles, write_als

    walled = tmp_path / "walled"
    shutil.copytree(scenario_dir, walled)
    scn = load_scenario(walled)
    ang, rad = np.meshgrid(np.radians(np.arange(0.0, 360.0, 0.5)), np.arange(10.0, 11.0, 0.5))
    sensor = scn.truth.sensor_pose[:3, 3]
    ring = np.column_stack([sensor[0] + rad.ravel() * np.cos(ang.ravel()),
                            sensor[1] + rad.ravel() * np.sin(ang.ravel()),
                            np.full(ang.size, 40.0)])
    xyz = np.vstack([np.asarray(scn.als.xyz, dtype=float), ring])
    cls = np.concatenate([scn.als.classification, np.full(len(ring), 6)])
    for tile in find_als_tiles(walled / "als"):
        tile.unlink()
    write_als(walled / "als" / "walled.laz", scn.frame.to_world(xyz), cls, scn.crs)
    out = tmp_path / "trk"
    assert main(["-q", "track", str(scenario_dir), "--out", str(out), "--oracle-pose"]) == 0
    capsys.readouterr()
    counts = {}
    for name, d in (("open", scenario_dir), ("walled", walled)):
        assert main(["evaluate", str(out), str(d / "ground_truth.json"), "--json"]) == 0
        counts[name] = json.loads(capsys.readouterr().out)["tracking"]
    assert counts["open"]["n_true"] > 5 and counts["walled"]["n_true"] == 0
