"""
Readings of the robot itself: a laser that sees its robot's posts, a bumper or a cable.

Such a reading has the same range wherever the robot goes, and the mapper draws it as a wall
along the whole path. The session warns of readings that keep their range while the laser
drives and turns (``scan.SelfHits``, cause ``self_hits``), and
``incremental.min_mapping_range`` leaves them out.
"""

import dataclasses

from conftest import radish_log
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.records import Scan
from polyline_mapper.recordings import make_drive
from polyline_mapper.replay import replay_records
from polyline_mapper.scan import SELF_HIT_MOTION, SelfHits
from polyline_mapper.session import SessionOptions
import pytest
from test_imperfect_poses import records, score

DRIVE = 'sim:office,step=0.1,turn=0.1'
"""The office at 10 Hz with turns in place taken gradually (a real robot's, not one scan's)."""
SCANS = 200
"""The drive's first scans: the posts are found at scan 118."""
POSTS = (45.0, 135.0, -45.0, -135.0)
"""Where the robot's four posts stand, degrees in the laser frame; 6 deg wide, at 0.25 m."""


@pytest.fixture(scope='module')
def drive():
    """Return the drive and its records (true poses on /tf) up to its ``SCANS``-th scan."""
    drive = make_drive(DRIVE, 1)
    out, n = [], 0
    for rec in records(drive):
        n += isinstance(rec, Scan)
        if n > SCANS:
            break
        out.append(rec)
    return drive, out


def with_posts(recs: list, seed: int = 0, reading: bool = True) -> list:
    """Return ``recs`` with the posts in every scan: 0.25 m, 2 cm of noise (or no return)."""
    rng = np.random.default_rng(seed)
    out = []
    for rec in recs:
        if isinstance(rec, Scan):
            ang = rec.angle_min + rec.angle_increment * np.arange(len(rec.ranges))
            ranges = np.array(rec.ranges, dtype=np.float32)
            for post in np.radians(POSTS):
                on = np.abs(np.angle(np.exp(1j * (ang - post)))) <= np.radians(3.0)
                ranges[on] = 0.25 + rng.normal(0.0, 0.02, on.sum()) if reading else np.nan
            rec = dataclasses.replace(rec, ranges=ranges)
        out.append(rec)
    return out


def mapped(recs: list, min_range: float = 0.0) -> tuple:
    """Replay ``recs``; return the session and its warnings (cause, text)."""
    warned = []
    session = replay_records(recs, config=IncrementalConfig(min_mapping_range=min_range),
                             options=SessionOptions(keep_points=True),
                             warn=lambda cause, text: warned.append((cause, text)))
    return session, warned


def test_the_robots_own_posts_are_warned_of_and_min_mapping_range_leaves_them_out(drive):
    drive, recs = drive
    clean, warned = mapped(recs)
    assert 'self_hits' not in [cause for cause, _ in warned]
    posts, warned = mapped(with_posts(recs))
    texts = [text for cause, text in warned if cause == 'self_hits']
    assert texts, warned
    # It names the laser, the four posts' sectors and the setting that leaves them out.
    assert texts[0].startswith("laser 'laser': ")
    assert '-135..-132, -48..-42, 42..48, 132..135 deg' in texts[0], texts[0]
    above = float(texts[0].split('min_mapping_range to ')[1].split(' m')[0])
    assert 0.3 < above < 0.45
    # The posts are drawn as walls along the path (13 segments on 7 walls without them, 23
    # with them); left out, the map is, bit for bit, that of a laser whose posts' beams had
    # no return.
    truth = [score(drive, s)['walls'] for s in (clean, posts)]
    assert truth[0]['precision'] == 1.0 and truth[1]['precision'] < 0.5, truth
    left_out, warned = mapped(with_posts(recs), min_range=above)
    assert 'self_hits' not in [cause for cause, _ in warned]
    assert score(drive, left_out)['walls']['precision'] == 1.0
    blind, _ = mapped(with_posts(recs, reading=False))
    assert np.array_equal(left_out.map_value().segments, blind.map_value().segments)


@pytest.mark.parametrize('name', ['intel', 'csail', 'infinite-corridor', 'freiburg-079',
                                  'freiburg-campus'])
def test_no_reading_of_the_real_logs_is_taken_for_the_robot(name):
    # No run of the same reading in them spans any turn in place while the laser drives 3 m,
    # nor any driving while it turns 90 deg in place (SELF_HIT_MOTION). With the first rule
    # (the heading's span, on any step) fr079's robot pivoting through doors came within
    # 1.73 m of 2 m at 90 deg.
    log = read_carmen(str(radish_log(f'{name}-corrected.log.gz')))
    hits = SelfHits()
    found = [k for k, rec in enumerate(log.records) if hits.add(rec.ranges, rec.pose, 0.0).any()]
    assert found == []


def ring_ranges(x, y, yaw, radii):
    """Ranges (360 beams, 1 deg) from a laser at (x, y, yaw) to the nearest of circles around 0."""
    a = yaw + np.radians(np.arange(360) - 180.0)
    dx, dy = np.cos(a), np.sin(a)
    out = np.full(360, np.inf)
    for radius in radii:
        b, c = x * dx + y * dy, x * x + y * y - radius * radius
        s = np.sqrt(np.maximum(b * b - c, 0.0))
        t = np.where(-b - s > 1e-6, -b - s, np.where(-b + s > 1e-6, -b + s, np.inf))
        out = np.minimum(out, np.where(b * b >= c, t, np.inf))
    return out


@pytest.mark.parametrize('how', ['around a ring corridor', 'in place in a round room'])
def test_round_walls_are_not_taken_for_the_robot(how):
    # Driving round a ring corridor 1 m from its inner wall (radius 2 m: a round building's
    # core, a tank inspected) keeps the side beams' ranges while the heading turns: the first
    # rule (3 m driven while the heading spanned 90 deg) warned 305 times and advised a
    # min_mapping_range of 1.55 m, dropping every wall that near (an audit). Turning in place
    # with the laser 0.2 m off the axis in a room of radius 1.2 m kept some after 2.4 turns.
    # Driving and turning in place now count apart: neither alone is the robot.
    rng = np.random.default_rng(0)
    hits = SelfHits()
    for k in range(1200):
        if how == 'around a ring corridor':
            phi = k * 0.05 / 3.0
            pose = np.array([3.0 * np.cos(phi), 3.0 * np.sin(phi), phi + np.pi / 2])
            radii = (2.0, 4.5)
        else:
            pose = np.array([0.2 * np.cos(0.1 * k), 0.2 * np.sin(0.1 * k), 0.1 * k])
            radii = (1.2,)
        ranges = ring_ranges(*pose, radii) + rng.normal(0.0, 0.01, 360)
        assert not hits.add(ranges, pose, 0.05).any(), k


def test_small_corrections_in_place_do_not_add_up_to_a_turn():
    # A robot following a corridor's wall 0.5 m off, drifting left 0.3 deg a scan while it
    # drives 0.05 m and turning back 5 deg in place every 17 scans: its heading stays within
    # 5 deg and the wall's beam keeps its range. Counting only the turns in place, they added
    # up to 90 deg and the rule (of 88ddd43) advised a min_mapping_range of 1.48 m, dropping
    # both walls (an audit); the heading's span must reach 90 deg too.
    hits, pose = SelfHits(), np.zeros(3)
    ranges = np.full(360, 5.0)
    ranges[90] = 0.5
    for k in range(2000):
        assert not hits.add(ranges, pose, 0.05).any(), k
        if k % 17 == 16:
            pose = pose + [0.0, 0.0, -np.radians(5.1)]
        else:
            pose = pose + [0.05 * np.cos(pose[2]), 0.05 * np.sin(pose[2]), np.radians(0.3)]


def test_a_reading_is_followed_only_through_motion_it_was_watched_in():
    # A post at 0.3 m; the laser turns in place 90 deg (0.1 rad a scan), then drives 0.1 m a
    # scan: found once it drove 3 m. Turned by a jump (a U-turn between two scans) or with
    # another beam count, it starts over there.
    def first_found(jump_at=None, recount_at=None):
        hits, pose = SelfHits(), np.zeros(3)
        for k in range(100):
            ranges = np.full(361 if recount_at is not None and k >= recount_at else 360, 5.0)
            ranges[10] = 0.3
            if k == jump_at:
                pose = pose + [0.0, 0.0, np.pi]
            if hits.add(ranges, pose, 0.05)[10]:
                return k
            turning = (k - (jump_at or recount_at or 0)) % 100 < 16
            pose = pose + ([0.0, 0.0, 0.1] if turning else
                           [0.1 * np.cos(pose[2]), 0.1 * np.sin(pose[2]), 0.0])
        return None
    assert SELF_HIT_MOTION == (3.0, np.radians(90.0))
    assert first_found() in (46, 47)                # 16 turning scans, then 30 driving ones
    assert first_found(jump_at=20) in (66, 67) and first_found(recount_at=20) in (66, 67)


@pytest.mark.parametrize('args, words', [
    (['--set', 'min_mapping_range=-1'], 'min_mapping_range must be in [0, 1e+06]'),
    (['--set', 'min_mapping_range=200'], 'min_mapping_range must be below max_mapping_range'),
])
def test_a_bad_min_mapping_range_is_refused_in_one_line(tmp_path, capsys, args, words):
    assert main(['replay', 'sim:office', '-o', str(tmp_path / 'm.json'), '-q'] + args) != 0
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / 'm.json').exists()
