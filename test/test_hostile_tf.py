"""Hostile /tf: junk frame names and stamp floods stay bounded; the SE(2) helpers in poses."""

import math
import time

import numpy as np
from polyline_mapper.formats.records import Transform
from polyline_mapper.poses import (FrameLimitError, mount_quaternion, planar_transform,
                                   quaternion_from_yaw, quaternion_matrix, se2_compose,
                                   se2_inverse, TransformBuffer2D)
import pytest

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def real_tree(buf, stamps):
    """Fill map -> odom -> base_link -> laser at ``stamps``; return the laser pose lookups."""
    buf.set_transform('base_link', 'laser', 0.0, (0.2, 0.0, 0.3), quaternion_from_yaw(0.1),
                      static=True)
    for t in stamps:
        buf.set_transform('map', 'odom', t, (1.0, -2.0, 0.0), quaternion_from_yaw(0.4))
        buf.set_transform('odom', 'base_link', t, (t, 0.5 * t, 0.0), quaternion_from_yaw(t))
    return [buf.lookup('map', 'laser', t + 0.05) for t in stamps[:-1]]


@pytest.mark.parametrize('per_message', [1, 100_000])
def test_100k_junk_frames_are_refused_beyond_the_limit_and_real_frames_keep_working(
        per_message):
    rng = np.random.default_rng(5)
    buf = TransformBuffer2D()
    stamps = np.arange(0.0, 2.0, 0.1)
    before = real_tree(buf, stamps)
    names = [f'junk_{i}_{v}' for i, v in enumerate(rng.integers(0, 1 << 30, 100_000))]
    refused, limit_errors = 0, 0
    for start in range(0, len(names), per_message):     # one TFMessage of `per_message`
        for name in names[start:start + per_message]:
            try:
                buf.set_transform('map', name, 1.0, (0.0, 0.0, 0.0), IDENTITY)
            except ValueError as exc:
                refused += 1
                limit_errors += isinstance(exc, FrameLimitError)
    frames = buf.frames()
    assert len(frames) == buf.max_frames == 10000
    assert refused == limit_errors == 100_000 - (10000 - 4)
    assert buf.entries() <= 10000 + 2 * len(stamps)
    assert {'map', 'odom', 'base_link', 'laser'} <= frames
    after = [buf.lookup('map', 'laser', t + 0.05) for t in stamps[:-1]]
    np.testing.assert_array_equal(after, before)
    # Known frames keep taking transforms; a frame dropped by re-hanging makes room again.
    buf.set_transform('odom', 'base_link', 2.0, (2.0, 1.0, 0.0), IDENTITY)
    with pytest.raises(FrameLimitError, match='max_frames'):
        buf.set_transform('map', 'one_more', 1.0, (0.0, 0.0, 0.0), IDENTITY)
    buf.set_transform('odom', names[0], 1.0, (0.0, 0.0, 0.0), IDENTITY)      # re-hung
    buf.clear(keep_static=True)
    assert buf.frames() == {'base_link', 'laser'}
    buf.set_transform('map', 'one_more', 1.0, (0.0, 0.0, 0.0), IDENTITY)


def test_a_junk_chain_deeper_than_max_depth_costs_bounded_time_and_spares_the_real_tree():
    buf = TransformBuffer2D()
    stamps = np.arange(0.0, 2.0, 0.1)
    before = real_tree(buf, stamps)
    start = time.perf_counter()
    for i in range(5000):                         # map <- j0 <- j1 <- ... <- j4999
        buf.set_transform('map' if i == 0 else f'j{i - 1}', f'j{i}', 0.0, (0, 0, 0), IDENTITY)
    rehang = 0
    for k in range(2000):                         # re-hang a deep known frame, back and forth
        try:
            buf.set_transform(f'j{4996 + k % 2}', 'j4999', 0.0, (0, 0, 0), IDENTITY)
        except FrameLimitError as exc:
            rehang += 1
            assert 'more than 1000 frames above it' in str(exc)
    seconds = time.perf_counter() - start
    assert rehang == 2000 and seconds < 10.0, seconds      # 5000 x 2000 steps before the cap
    with pytest.raises(LookupError) as err:
        buf.lookup('map', 'j4000', 0.0)
    assert err.value.cause == 'too_deep' and not err.value.curable
    assert buf.lookup('map', 'j500', 0.0)[0] == 0.0
    after = [buf.lookup('map', 'laser', t + 0.05) for t in stamps[:-1]]
    np.testing.assert_array_equal(after, before)


def test_300k_stamps_on_one_edge_stay_bounded_and_each_insert_costs_the_same():
    buf = TransformBuffer2D()                   # 30 s cache: 300k stamps 0.1 ms apart all fit
    buf.set_transform('base_link', 'laser', 0.0, (0.2, 0.0, 0.0), IDENTITY, static=True)
    n, block = 300_000, 10_000
    q = quaternion_from_yaw(0.3)
    seconds = []
    start = time.perf_counter()
    for b in range(n // block):
        t0 = time.perf_counter()
        for i in range(b * block, (b + 1) * block):
            buf.set_transform('odom', 'base_link', i * 1e-4, (i * 1e-5, 0.0, 0.0), q)
        seconds.append(time.perf_counter() - t0)
    total = time.perf_counter() - start
    assert buf.entries() == 1 + buf.max_entries == 1 + 10000
    assert total < 30.0, seconds                # a few seconds alone on a slow 2-core VM
    # Linear: the last blocks (buffer full, dropping the oldest) cost about what the first did.
    assert min(seconds[-3:]) < 3.0 * min(seconds[:3]), seconds
    newest = (n - 1) * 1e-4
    pose = buf.lookup('odom', 'laser', newest - 0.5e-4)
    assert pose[0] == pytest.approx((n - 1.5) * 1e-5 + 0.2 * math.cos(0.3), abs=1e-9)
    with pytest.raises(LookupError) as err:      # older than the 10000 kept: refused
        buf.lookup('odom', 'laser', newest - 2.0)
    assert err.value.cause == 'too_old'


def test_late_and_repeated_stamps_keep_the_newest_entries_within_cache_and_cap():
    rng = np.random.default_rng(11)
    cache, cap = 2.0, 50
    buf = TransformBuffer2D(cache_seconds=cache, max_entries=cap)
    kept = {}                                   # reference: stamp -> x of the kept transforms
    newest = 0.0
    for k in range(5000):
        r = rng.random()
        t = newest + rng.exponential(0.02) if r < 0.6 or not kept else (
            rng.choice(list(kept)) if r < 0.7 else newest - rng.uniform(0.0, 3.0))
        t = float(t)
        buf.set_transform('odom', 'base_link', t, (float(k), 0.0, 0.0), IDENTITY)
        kept[t] = float(k)
        newest = max(newest, t)
        live = sorted(s for s in kept if s >= newest - cache)[-cap:]
        kept = {s: kept[s] for s in live}
        assert buf.entries() == len(kept)
        if k % 50 == 0:
            for s, x in kept.items():
                assert buf.lookup('odom', 'base_link', s)[0] == x


@pytest.mark.parametrize('kwargs', [{'max_entries': 1}, {'max_frames': 0}, {'max_entries': 2.5},
                                    {'max_frames': True}])
def test_bad_limits_are_refused(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        TransformBuffer2D(**kwargs)


def test_se2_compose_and_inverse_vectorised_and_single():
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-4, 4, (50, 3)), rng.uniform(-4, 4, (50, 3))
    ab = se2_compose(a, b)
    assert ab.shape == (50, 3)
    for i in range(50):
        np.testing.assert_array_equal(se2_compose(a[i], b[i]), ab[i])
        c, s = math.cos(a[i, 2]), math.sin(a[i, 2])
        want = [a[i, 0] + c * b[i, 0] - s * b[i, 1], a[i, 1] + s * b[i, 0] + c * b[i, 1],
                a[i, 2] + b[i, 2]]
        np.testing.assert_allclose(ab[i], want, atol=1e-12)
    np.testing.assert_allclose(se2_compose(a, se2_inverse(a)), 0.0, atol=1e-12)
    np.testing.assert_allclose(se2_compose(se2_inverse(a), a), 0.0, atol=1e-12)
    np.testing.assert_array_equal(se2_compose(a, b[0][None]), se2_compose(a, b[0]))
    assert se2_inverse(a[0]).shape == (3,)


def test_planar_transform_and_mount_quaternion_place_the_child_like_the_buffer():
    rng = np.random.default_rng(4)
    for yaw, upside_down in zip(rng.uniform(-3, 3, 8), [False, True] * 4):
        pose = rng.uniform(-2, 2, 3)
        tr = planar_transform(1.5, 'base_link', 'laser', pose, static=True,
                              quaternion=mount_quaternion(yaw, upside_down))
        assert isinstance(tr, Transform) and tr.static and tr.stamp == 1.5
        np.testing.assert_array_equal(tr.translation, [pose[0], pose[1], 0.0])
        rot = quaternion_matrix(tr.rotation)
        assert math.atan2(rot[1, 0], rot[0, 0]) == pytest.approx(yaw, abs=1e-12)
        assert rot[2, 2] == pytest.approx(-1.0 if upside_down else 1.0, abs=1e-12)
        buf = TransformBuffer2D()
        buf.set_transform(tr.parent, tr.child, tr.stamp, tr.translation, tr.rotation, tr.static)
        got = buf.lookup_planar('base_link', 'laser', 0.0)
        assert got.flip == upside_down and got.yaw == pytest.approx(yaw, abs=1e-12)
    tr = planar_transform(2, 'odom', 'base_link', (1, 2, 0.5))
    np.testing.assert_array_equal(tr.rotation, quaternion_from_yaw(0.5))
    assert not tr.static and tr.parent == 'odom' and tr.child == 'base_link'


def test_a_translation_beyond_1e8_m_is_refused_not_composed_into_a_pose(tmp_path, capsys):
    # A CARMEN laser offset of 1e300 m became base_link -> laser, and map -> odom its inverse:
    # composed, nothing was left of the poses (every scan mapped at x = 0, a wrong map, no
    # warning). The transform is refused (bad_transform), the replay ends with one line.
    from polyline_mapper.cli import main
    buf = TransformBuffer2D()
    buf.set_transform('utm', 'map', 0.0, (6.5e5, 9.9e6, 0.0), IDENTITY)   # a southern UTM
    for far in (1e12, -1e300):
        with pytest.raises(ValueError, match=r'lies beyond \+-1e\+08 m'):
            buf.set_transform('map', 'odom', 1.0, (far, 0.0, 0.0), IDENTITY)
    assert buf.frames() == {'utm', 'map'}
    from test_hostile_cli import carmen_text
    log = tmp_path / 'far.log'
    log.write_text('PARAM robot_frontlaser_offset 1e300\n' + carmen_text(scans=12))
    out = tmp_path / 'm.json'
    assert main(['replay', str(log), '-o', str(out), '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('polyline-mapper: error:'), err
    assert 'no scan could be mapped' in err[0] and 'lies beyond +-1e+08 m' in err[0], err
    assert not out.exists()


def test_one_off_frames_expire_so_the_limit_never_stops_the_robot_for_good():
    # A live-node audit: a tracker's 12000 one-off frames (world -> obj_i, each sent once)
    # filled the tree, and 40 s later (beyond the 30 s cache) the robot's own transforms were
    # still refused: the node never mapped again. Frames whose transforms all lie beyond the
    # cache before the newest now make room; fresh ones still count.
    buf = TransformBuffer2D()
    buf.set_transform('base_link', 'laser', 0.0, (0.2, 0.0, 0.1), IDENTITY, static=True)
    refused = 0
    for i in range(12_000):
        try:
            buf.set_transform('world', f'obj_{i}', 900.0 + 1e-3 * i, (1.0, 0.0, 0.0), IDENTITY)
        except FrameLimitError:
            refused += 1
    assert refused == 12_000 - (buf.max_frames - 3) and len(buf.frames()) == buf.max_frames
    with pytest.raises(FrameLimitError):          # within the cache: the junk still counts
        buf.set_transform('odom', 'base_link', 920.0, (0.0, 0.0, 0.0), IDENTITY)
    for t in np.arange(940.0, 945.0, 0.1):
        buf.set_transform('odom', 'base_link', t, (t - 940.0, 0.0, 0.0), IDENTITY)
    assert buf.lookup('odom', 'laser', 944.0)[0] == pytest.approx(4.2)
    assert not any(name.startswith('obj_') for name in buf.frames())


def test_a_stray_second_parent_never_replaces_a_static_mount():
    # A live-node audit: one dynamic other -> laser beside the static base_link -> laser
    # re-hung the laser; the mount, sent once on /tf_static, was gone for good and every later
    # scan was 'not connected'. The stray transform is refused, saying why.
    buf = TransformBuffer2D()
    buf.set_transform('base_link', 'laser', 0.0, (0.2, 0.0, 0.1), IDENTITY, static=True)
    for t in np.arange(0.0, 1.0, 0.1):
        buf.set_transform('odom', 'base_link', t, (t, 0.0, 0.0), IDENTITY)
    for parent in ('other', 'odom', 'base_link'):
        with pytest.raises(ValueError, match="refused: 'laser' has the static parent "
                           "'base_link'" if parent != 'base_link' else 'it is static'):
            buf.set_transform(parent, 'laser', 0.5, (0.0, 0.0, 0.0), IDENTITY)
    assert buf.lookup('odom', 'laser', 0.5)[0] == pytest.approx(0.7)
    # a new static mount (the robot's description sent again, changed) still replaces it
    buf.set_transform('base_link', 'laser', 0.0, (0.3, 0.0, 0.1), IDENTITY, static=True)
    assert buf.lookup('odom', 'laser', 0.5)[0] == pytest.approx(0.8)
