"""Positions in the contract (docs/map.md): optional and backward compatible in the sensor log,
true positions from the simulator, Odometry/NavSatFix through the bag import, and each soil
estimate's place: the contact patches of the wheels that informed it."""

from __future__ import annotations

import json
import math

import pytest

from soilocp.schemas.pipeline import SoilEstimate
from soilocp.schemas.sensor import SensorSample, parse_sensor_line
from soilocp.estimation.pipeline import VehiclePipeline
from soilocp.map.place import estimate_place, geo_to_local, local_to_geo
from soilocp.model.vehicle import DEFAULT_VEHICLE
from soilocp.sim.field import Field, Region, StartPose, straight_drive
from soilocp.sim.simulator import simulate

START = StartPose(frame="field", x=10.0, y=-5.0, heading=0.5, geo_origin=(46.5, 6.6))


@pytest.fixture(scope="module")
def drive():
    return list(simulate("sand", duration=4.0, seed=3, start=START))


def test_old_samples_are_unchanged_and_positions_optional():
    plain = next(iter(simulate("sand", duration=0.05, seed=0)))[0]
    text = plain.model_dump_json()
    assert "position" not in text and "geo" not in text  # logs without positions stay byte for byte
    assert parse_sensor_line(text) == plain
    d = json.loads(text)
    d["position"] = {"frame": "map", "x": 1.5, "y": -2.0}
    d["geo"] = {"latitude": 47.1, "longitude": 8.2, "heading": 1.0}
    s = parse_sensor_line(json.dumps(d))
    assert s.position.x == 1.5 and s.position.heading is None and s.geo.latitude == 47.1
    assert parse_sensor_line(s.model_dump_json()) == s


@pytest.mark.parametrize("patch, field", [
    ({"geo": {"latitude": 91.0, "longitude": 0.0}}, "geo.latitude"),
    ({"geo": {"latitude": 0.0, "longitude": -181.0}}, "geo.longitude"),
    ({"position": {"frame": "a/b", "x": 0.0, "y": 0.0}}, "position.frame"),
    ({"position": {"frame": "map", "x": 2e7, "y": 0.0}}, "position.x"),
    ({"position": {"frame": "map", "x": 0.0}}, "position.y"),
    ({"position": {"frame": "map", "x": 0.0, "y": 0.0, "z": 1.0}}, "position.z"),
])
def test_bad_positions_are_rejected_naming_the_field(patch, field):
    d = json.loads(next(iter(simulate("sand", duration=0.05, seed=0)))[0].model_dump_json())
    d.update(patch)
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        parse_sensor_line(json.dumps(d))


def test_simulator_writes_true_positions(drive):
    for s, t in drive[::50]:
        # the CoM moves along its heading from the start pose; truth and sample agree
        assert s.position.frame == "field"
        assert (s.position.x, s.position.y) == (t.x, t.y)
        assert s.position.heading == pytest.approx(START.heading + t.heading)
        assert math.hypot(t.x - START.x, t.y - START.y) == pytest.approx(t.distance, rel=1e-3, abs=1e-6)
        east, north = geo_to_local(START.geo_origin, s.geo.latitude, s.geo.longitude)
        assert (east, north) == pytest.approx((t.x, t.y), abs=1e-6)
    s, t = drive[-1]
    assert t.distance > 2.0
    assert math.atan2(t.y - START.y, t.x - START.x) == pytest.approx(START.heading, abs=0.02)


def test_soil_estimates_carry_the_informing_wheels_contact_patches(drive):
    pipe = VehiclePipeline()
    placed = 0
    for s, _t in drive:
        soil: SoilEstimate = pipe.process_all(s)[2]
        used = [i + 1 for i, u in enumerate(soil.informative) if u]
        if not used:
            assert soil.where is None
            continue
        placed += 1
        w = soil.where
        assert list(w.wheels) == used and w.frame == "field"
        h = s.position.heading
        for wheel, (x, y) in zip(w.wheels, w.xy):
            bx, by = DEFAULT_VEHICLE.wheel_x[wheel - 1], DEFAULT_VEHICLE.wheel_y[wheel - 1]
            assert x == pytest.approx(s.position.x + math.cos(h) * bx - math.sin(h) * by, abs=1e-9)
            assert y == pytest.approx(s.position.y + math.sin(h) * bx + math.cos(h) * by, abs=1e-9)
            # the WGS84 patch is the same point on the tangent plane
            lat, lon = w.latlon[w.wheels.index(wheel)]
            assert geo_to_local(START.geo_origin, lat, lon) == pytest.approx((x, y), abs=1e-3)
        assert SoilEstimate.model_validate_json(soil.model_dump_json()) == soil
    assert placed > len(drive) // 2


def test_no_position_no_place_and_no_heading_puts_patches_at_the_com():
    from soilocp.schemas.position import MapPosition

    assert estimate_place(DEFAULT_VEHICLE, None, None, (True,) * 4) is None
    p = MapPosition(frame="m", x=3.0, y=4.0)
    assert estimate_place(DEFAULT_VEHICLE, p, None, (False,) * 4) is None
    w = estimate_place(DEFAULT_VEHICLE, p, None, (False, True, True, False))
    assert w.wheels == (2, 3) and w.xy == ((3.0, 4.0), (3.0, 4.0))
    lat, lon = local_to_geo((10.0, 20.0), 100.0, -50.0)
    assert geo_to_local((10.0, 20.0), lat, lon) == pytest.approx((100.0, -50.0), abs=1e-9)


def test_straight_drive_segments_follow_the_field():
    f = Field((Region("sand", 0, 10, -5, 5), Region("grass", 10, 20, -5, 5)), background="firm")
    sc = straight_drive(f, StartPose(x=-2.0, y=0.0), 30.0)
    assert [s.soil_class for s in sc.segments] == ["firm", "sand", "grass", "firm"]
    assert [s.length for s in sc.segments[:3]] == pytest.approx([2.0, 10.0, 10.0], abs=0.051)


def test_bag_import_maps_odometry_pose_and_navsatfix(tmp_path, drive):
    from soilocp.ingest.bag_writer import WHEEL_JOINTS, write_bag
    from soilocp.ingest.mapfile import TopicMap
    from soilocp.ingest.rosbag_import import import_bag

    samples = [s for s, _t in drive]
    write_bag(samples, tmp_path / "bag")
    base = dict(vehicle_id="rover1", imu={"topic": "/imu/data"},
                joint_states={"topic": "/joint_states", "wheels": list(WHEEL_JOINTS)}, ground_speed={"topic": "/odom"})
    tm = TopicMap.model_validate({**base, "position": {"topic": "/odom"}, "geo": {"topic": "/fix"}})
    prov, issues = import_bag(tmp_path / "bag", tm, tmp_path / "out.jsonl", progress=False)
    assert issues == []
    got = [SensorSample.model_validate_json(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    by_stamp = {round(s.stamp, 3): s for s in samples}
    checked = 0
    for g in got:
        src = by_stamp.get(round(g.stamp - 1_700_000_000, 3))
        if src is None or g.position is None:
            continue
        # the odometry comes every 5th sample: the tick holds the newest pose at or before it
        assert g.position.frame == "field"
        assert math.hypot(g.position.x - src.position.x, g.position.y - src.position.y) < 0.06
        assert g.position.heading == pytest.approx(src.position.heading, abs=1e-6)
        assert geo_to_local(START.geo_origin, g.geo.latitude, g.geo.longitude) == pytest.approx(
            (g.position.x, g.position.y), abs=1e-3)
        checked += 1
    assert checked > len(got) * 0.9
    # without the position keys the same bag imports without positions, exactly as before
    tm0 = TopicMap.model_validate(base)
    import_bag(tmp_path / "bag", tm0, tmp_path / "plain.jsonl", progress=False)
    assert all("position" not in line for line in (tmp_path / "plain.jsonl").read_text().splitlines())
