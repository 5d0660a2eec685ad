"""TransformBuffer2D: chained, interpolated, bounded frame lookups projected to the plane."""

import math

import numpy as np
from polyline_mapper.poses import (PlanarPose, quaternion_from_yaw, quaternion_matrix,
                                   TransformBuffer2D, TransformLookupError, yaw_from_quaternion)
from polyline_mapper.scan import scan_to_points
import pytest

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def quaternion_rpy(roll, pitch, yaw):
    """Return the unit quaternion (x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])


def se2(a, b):
    """Compose planar poses: b expressed in a's frame, a in the world -> b in the world."""
    x, y, t = a
    return np.array([x + math.cos(t) * b[0] - math.sin(t) * b[1],
                     y + math.sin(t) * b[0] + math.cos(t) * b[1], wrap(t + b[2])])


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def put(buf, parent, child, stamp, pose, z=0.0, static=False):
    buf.set_transform(parent, child, stamp, (pose[0], pose[1], z), quaternion_from_yaw(pose[2]),
                      static=static)


def test_yaw_from_quaternion_matches_the_rotation_matrix():
    rng = np.random.default_rng(1)
    for roll, pitch, yaw in rng.uniform(-math.pi, math.pi, (50, 3)) * [0.3, 0.3, 1.0]:
        q = quaternion_rpy(roll, pitch, yaw)
        r = quaternion_matrix(q)
        assert yaw_from_quaternion(*q) == pytest.approx(math.atan2(r[1, 0], r[0, 0]), abs=1e-12)
        assert yaw_from_quaternion(*quaternion_from_yaw(yaw)) == pytest.approx(yaw, abs=1e-12)


def test_chain_map_odom_base_laser_composes_like_se2():
    rng = np.random.default_rng(2)
    buf = TransformBuffer2D()
    mount = np.array([0.25, -0.1, 0.3])
    put(buf, 'base_link', 'laser', 0.0, mount, z=0.4, static=True)
    stamps = np.arange(0.0, 5.01, 0.5)
    map_odom, odom_base = rng.uniform(-1, 1, (11, 3)), rng.uniform(-5, 5, (11, 3))
    for t, m_o, o_b in zip(stamps, map_odom, odom_base):
        put(buf, 'map', 'odom', t, m_o)
        put(buf, 'odom', 'base_link', t, o_b)
    # At a stored stamp the lookup is the exact SE(2) composition of the three edges.
    for t, m_o, o_b in zip(stamps, map_odom, odom_base):
        want = se2(se2(m_o, o_b), mount)
        got = buf.lookup('map', 'laser', t)
        assert np.allclose(got[:2], want[:2], atol=1e-9) and abs(wrap(got[2] - want[2])) < 1e-9
        # ... and the inverse lookup undoes it.
        back = buf.lookup('laser', 'map', t)
        assert np.allclose(se2(got, back), 0.0, atol=1e-9)
    # A static edge holds at any time; a lookup within one subtree ignores the rest.
    assert np.allclose(buf.lookup('base_link', 'laser', 1e6), mount)
    assert buf.entries() == 1 + 2 * 11


def test_interpolation_is_linear_in_xy_and_takes_the_short_way_round_in_yaw():
    buf = TransformBuffer2D()
    put(buf, 'odom', 'base_link', 10.0, (0.0, 0.0, 3.0))
    put(buf, 'odom', 'base_link', 11.0, (2.0, -1.0, -3.0))
    got = buf.lookup('odom', 'base_link', 10.25)
    assert np.allclose(got[:2], [0.5, -0.25])
    # From 3.0 to -3.0 rad the short way crosses pi (0.283 rad), not 0 (6 rad).
    assert wrap(got[2] - (3.0 + 0.25 * (2 * math.pi - 6.0))) == pytest.approx(0.0, abs=1e-9)
    mid = buf.lookup('odom', 'base_link', 10.5)
    assert abs(wrap(mid[2] - math.pi)) < 1e-9


def test_stamps_outside_the_buffer_within_tolerance_hold_the_nearest_else_fail():
    buf = TransformBuffer2D()
    put(buf, 'odom', 'base_link', 1.0, (1.0, 0.0, 0.0))
    put(buf, 'odom', 'base_link', 2.0, (2.0, 0.0, 0.0))
    assert buf.lookup('odom', 'base_link', 2.05, tolerance=0.1)[0] == 2.0   # held
    assert buf.lookup('odom', 'base_link', 0.95, tolerance=0.1)[0] == 1.0
    with pytest.raises(TransformLookupError, match='after the newest') as err:
        buf.lookup('odom', 'base_link', 2.2, tolerance=0.1)
    assert err.value.cause == 'too_new' and isinstance(err.value, LookupError)
    with pytest.raises(TransformLookupError, match='before the oldest') as err:
        buf.lookup('odom', 'base_link', 0.5, tolerance=0.1)
    assert err.value.cause == 'too_old'
    # One stored entry: usable only within the tolerance of its stamp.
    put(buf, 'base_link', 'laser', 3.0, (0.1, 0.0, 0.0))
    with pytest.raises(TransformLookupError) as err:
        buf.lookup('odom', 'laser', 1.5)
    assert err.value.cause == 'too_old'


@pytest.mark.parametrize('target, source, cause', [
    ('map', 'laser', 'unknown_frame'),
    ('odom', 'bogus', 'unknown_frame'),
    ('odom', 'other_laser', 'not_connected'),
])
def test_lookup_failures_name_their_cause(target, source, cause):
    buf = TransformBuffer2D()
    with pytest.raises(TransformLookupError) as err:
        buf.lookup('odom', 'laser', 0.0)
    assert err.value.cause == 'no_tf'
    put(buf, 'odom', 'base_link', 0.0, (0, 0, 0))
    put(buf, 'base_link', 'laser', 0.0, (0, 0, 0), static=True)
    put(buf, 'world', 'other_laser', 0.0, (0, 0, 0), static=True)
    with pytest.raises(TransformLookupError) as err:
        buf.lookup(target, source, 0.0)
    assert err.value.cause == cause and str(err.value)


def test_memory_is_bounded_by_the_cache_length():
    buf = TransformBuffer2D(cache_seconds=5.0)
    for i in range(10000):                     # 100 s at 100 Hz
        put(buf, 'odom', 'base_link', i * 0.01, (i * 0.001, 0, 0))
    assert buf.entries() <= 501
    assert buf.lookup('odom', 'base_link', 99.0)[0] == pytest.approx(9.9)
    with pytest.raises(TransformLookupError):
        buf.lookup('odom', 'base_link', 50.0)


def test_out_of_order_and_repeated_stamps():
    buf = TransformBuffer2D()
    for t in (3.0, 1.0, 2.0, 2.0):
        put(buf, 'odom', 'base_link', t, (t, 0, 0))
    assert buf.entries() == 3
    assert buf.lookup('odom', 'base_link', 1.5)[0] == pytest.approx(1.5)


def test_a_new_parent_rehangs_the_frame_and_loops_are_refused():
    buf = TransformBuffer2D()
    put(buf, 'odom', 'base_link', 0.0, (1, 0, 0))
    put(buf, 'map', 'base_link', 0.0, (5, 0, 0))
    assert buf.lookup('map', 'base_link', 0.0)[0] == 5.0
    with pytest.raises(TransformLookupError) as err:
        buf.lookup('odom', 'base_link', 0.0)
    assert err.value.cause == 'unknown_frame'
    put(buf, 'base_link', 'laser', 0.0, (0, 0, 0), static=True)
    with pytest.raises(ValueError, match='loop'):
        put(buf, 'laser', 'map', 0.0, (0, 0, 0))


@pytest.mark.parametrize('args, match', [
    (('', 'a', 0.0, (0, 0, 0), IDENTITY), 'empty'),
    (('a', 'a', 0.0, (0, 0, 0), IDENTITY), 'itself'),
    (('a', 'b', float('nan'), (0, 0, 0), IDENTITY), 'stamp'),
    (('a', 'b', 0.0, (0, float('inf'), 0), IDENTITY), 'translation'),
    (('a', 'b', 0.0, (0, 0), IDENTITY), 'translation'),
    (('a', 'b', 0.0, (0, 0, 0), (0, 0, 0, 0)), 'normalised'),
    (('a', 'b', 0.0, (0, 0, 0), (0, 0, 0.5, 0.5)), 'normalised'),
    (('a', 'b', 0.0, (0, 0, 0), (0, 0, float('nan'), 1)), 'quaternion'),
])
def test_bad_transforms_are_refused(args, match):
    buf = TransformBuffer2D()
    with pytest.raises(ValueError, match=match):
        buf.set_transform(*args)
    assert buf.entries() == 0
    with pytest.raises(ValueError):
        TransformBuffer2D(cache_seconds=0.0)


def test_clear_can_keep_the_static_transforms():
    buf = TransformBuffer2D()
    put(buf, 'base_link', 'laser', 0.0, (0.2, 0, 0), static=True)
    put(buf, 'odom', 'base_link', 5.0, (1, 0, 0))
    buf.clear(keep_static=True)
    assert buf.frames() == {'base_link', 'laser'} and buf.entries() == 1
    buf.clear()
    assert buf.entries() == 0


def test_leading_slashes_are_ignored_like_tf2():
    buf = TransformBuffer2D()
    put(buf, '/odom', '/base_link', 0.0, (1, 2, 0))
    assert np.allclose(buf.lookup('odom', 'base_link', 0.0), [1, 2, 0])


def beam_ends_3d(rot, trans, ranges, angles):
    """Ground truth: beam end points in 3D through the full transform, then dropped to xy."""
    local = np.stack([ranges * np.cos(angles), ranges * np.sin(angles), np.zeros_like(angles)])
    return (rot @ local).T[:, :2] + trans[:2]


@pytest.mark.parametrize('roll, pitch', [(0.0, 0.0), (math.pi, 0.0), (0.0, math.pi)])
def test_mounts_rotated_or_upside_down_give_the_true_beam_end_points(roll, pitch):
    rng = np.random.default_rng(3)
    ranges = rng.uniform(0.5, 8.0, 181)
    angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
    for yaw in (0.0, math.pi / 2, -2.0):
        buf = TransformBuffer2D()
        put(buf, 'odom', 'base_link', 0.0, (1.0, -2.0, 0.7))
        buf.set_transform('base_link', 'laser', 0.0, (0.3, 0.1, 0.5),
                          quaternion_rpy(roll, pitch, yaw), static=True)
        rot, trans = buf.lookup_matrix('odom', 'laser', 0.0)
        pose = buf.lookup_planar('odom', 'laser', 0.0)
        assert pose.flip == (roll != 0.0 or pitch != 0.0)
        pts = scan_to_points(ranges, pose.beam_angles(angles), pose.xyz)
        assert np.allclose(pts, beam_ends_3d(rot, trans, ranges, angles), atol=1e-9)
        if pose.flip:
            with pytest.raises(TransformLookupError) as err:
                buf.lookup('odom', 'laser', 0.0)
            assert err.value.cause == 'flipped'
        else:
            assert np.allclose(buf.lookup('odom', 'laser', 0.0), pose.xyz)


def test_a_laser_yawed_90_degrees_sees_straight_ahead_with_its_minus_90_beam():
    buf = TransformBuffer2D()
    put(buf, 'base_link', 'laser', 0.0, (0.0, 0.0, math.pi / 2), static=True)
    pose = buf.lookup_planar('base_link', 'laser', 0.0)
    pt = scan_to_points([2.0], pose.beam_angles([-math.pi / 2]), pose.xyz)
    assert np.allclose(pt, [[2.0, 0.0]])


def test_tilted_frames_are_refused_small_tilts_pass():
    buf = TransformBuffer2D()
    buf.set_transform('base_link', 'laser', 0.0, (0, 0, 0), quaternion_rpy(0.0, 0.1, 0.0), True)
    buf.set_transform('base_link', 'tilted', 0.0, (0, 0, 0), quaternion_rpy(0.6, 0.0, 0.0), True)
    assert not buf.lookup_planar('base_link', 'laser', 0.0).flip
    with pytest.raises(TransformLookupError, match='tilted 34.4 deg') as err:
        buf.lookup_planar('base_link', 'tilted', 0.0)
    assert err.value.cause == 'tilted'


def test_planar_pose_helpers():
    p = PlanarPose(1.0, 2.0, 0.5, flip=True)
    assert np.array_equal(p.xyz, [1.0, 2.0, 0.5])
    assert np.array_equal(p.beam_angles([0.1, -0.2]), [-0.1, 0.2])
    assert np.array_equal(PlanarPose(0, 0, 0).beam_angles([0.1]), [0.1])


def test_static_mount_is_the_lasers_pose_under_the_frame_its_static_transforms_hang_from():
    # replay --config compares it with the node's laser_* (odom mode): the mount replay took
    # from /tf_static, in any mode, before any dynamic transform (odom mode has none on /tf).
    from polyline_mapper.core.geometry import se2_compose
    from polyline_mapper.formats.records import Transform
    from polyline_mapper.session import PoseSource, SessionOptions
    ps = PoseSource(SessionOptions(pose_source='odom'))
    for parent, child, xy, yaw in (('base_link', 'plate', (0.2, 0.1), 0.5),
                                   ('plate', 'laser', (0.05, 0.0), -0.25)):
        ps.add(Transform(1.0, parent, child, np.array([*xy, 0.3]),
                         quaternion_from_yaw(yaw), True))
    top, pose = ps.static_mount('laser')
    want = se2_compose(np.array([0.2, 0.1, 0.5]), np.array([0.05, 0.0, -0.25]))
    assert top == 'base_link' and np.allclose([pose.x, pose.y, pose.yaw], want)
    assert ps.static_mount('base_link') is None and ps.static_mount('unknown') is None
