"""Offline loop closure (core.loops): loops found by matching, the pose graph, the band."""

import numpy as np
from polyline_mapper.core.loops import BAND, chain, corrections, Edge, find_loops, optimize, \
    relative, settle
from polyline_mapper.poses import se2_compose
from polyline_mapper.sim import LaserSpec, office_floor
from polyline_mapper.sim.laser import simulate_scan
from polyline_mapper.sim.world import path_poses, World

LOOP_COV = np.diag([0.02 ** 2, 0.02 ** 2, 0.01 ** 2])


def square_loop():
    """
    Return true keyframe poses round a 10 m square (every 0.5 m), and the same drifted.

    The drift: every step turned 0.004 rad more and 2 % longer than it was; the first pose is
    true. Returns (truth (K, 3), drifted (K, 3)).
    """
    truth = path_poses([(0, 0), (10, 0), (10, 10), (0, 10), (0, 0)], 0.5)
    steps = relative(truth[:-1], truth[1:])
    steps[:, 0] *= 1.02
    steps[:, 2] += 0.004
    drifted = [truth[0]]
    for s in steps:
        drifted.append(se2_compose(drifted[-1], s))
    return truth, np.array(drifted)


def test_the_pose_graph_closes_a_drifted_loop():
    truth, drifted = square_loop()
    k = len(truth) - 1
    off = np.hypot(*(drifted[:, :2] - truth[:, :2]).T)
    assert off[-1] > 1.0                                  # 1.6 m off when it comes back
    # the robot back at its start sees what it saw at its first three poses: the true relative
    # poses, as a match gives them
    loops = [Edge(a, b, relative(truth[a], truth[b]), LOOP_COV)
             for a, b in ((0, k), (1, k), (2, k - 1))]
    loops, active = settle(drifted, loops)
    assert active.all()                                   # far beyond the band: all move it
    after, kept = optimize(drifted, chain(drifted) + loops)
    assert len(kept) == 3
    err = np.hypot(*(after[:, :2] - truth[:, :2]).T)
    assert err.max() < 0.35 and err[-1] < 0.05, (err.max(), err[-1])
    assert np.sqrt(np.mean(err ** 2)) < 0.2 * np.sqrt(np.mean(off ** 2))
    assert np.array_equal(after[0], drifted[0])           # the first pose is held


def test_a_false_loop_is_dropped_by_the_pose_graph():
    truth, drifted = square_loop()
    k = len(truth) - 1
    right = [Edge(a, b, relative(truth[a], truth[b]), LOOP_COV)
             for a, b in ((0, k), (1, k), (2, k - 1), (3, k - 2))]
    # a wrong place: keyframe 40 (a corner) taken for keyframe 10's place, 1.5 m and 0.3 rad
    # off what it is
    z = se2_compose(relative(truth[10], truth[40]), (1.5, 0.0, 0.3))
    false = Edge(10, 40, z, LOOP_COV)
    good, _ = optimize(drifted, chain(drifted) + right)
    after, kept = optimize(drifted, chain(drifted) + right + [false])
    assert (10, 40) not in {(e.a, e.b) for e in kept} and len(kept) == len(right)
    assert np.allclose(after, good)


def test_loops_that_agree_with_the_trajectory_hold_it():
    # a loop within the band of the trajectory's own relative pose is replaced by it: the graph
    # then moves nothing
    truth, _ = square_loop()
    k = len(truth) - 1
    noisy = se2_compose(relative(truth[0], truth[k]), (0.05, -0.04, 0.02))
    loops, active = settle(truth, [Edge(0, k, noisy, LOOP_COV)])
    assert not active.any() and np.allclose(loops[0].z, relative(truth[0], truth[k]))
    after, _ = optimize(truth, chain(truth) + loops)
    assert np.abs(after - truth).max() < 1e-9
    beyond = se2_compose(relative(truth[0], truth[k]), (BAND[0] + 0.01, 0.0, 0.0))
    assert settle(truth, [Edge(0, k, beyond, LOOP_COV)])[1].all()


def test_corrections_move_each_stamp_by_its_keyframes():
    before = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    after = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.0], [2.0, 0.4, 0.0]])
    fix = corrections(before, after, np.array([0.0, 1.0, 2.0]), np.array([-1.0, 0.5, 1.5, 3.0]))
    assert np.allclose(fix, [[0, 0, 0], [0, 0.1, 0], [0, 0.3, 0], [0, 0.4, 0]])


def _scan(world, pose, rng):
    """Return a simulated scan's points in the laser frame."""
    spec = LaserSpec(noise=0.01, dropout=0.0)
    ranges, _ = simulate_scan(world, pose, spec, rng)
    a = spec.angles()
    ok = np.isfinite(ranges)
    return np.column_stack([ranges[ok] * np.cos(a[ok]), ranges[ok] * np.sin(a[ok])])


def test_find_loops_takes_a_true_return_and_refuses_another_room():
    # Three keyframes: the bottom-left room of the office, the corridor's far end, then back
    # in the room, where the trajectory has drifted 0.25 m and 0.08 rad. The third scan is taken
    # from its true pose (a loop: found, at the true relative pose, not the drifted one) or from
    # the top-right room or the corridor (the trajectory says the same place: no loop). (A scan
    # from the middle room below, 7 m east, is matched 1 m off: rooms alike; the pose graph
    # is what drops such a loop, test_a_false_loop_is_dropped_by_the_pose_graph.)
    world, rng = office_floor(), np.random.default_rng(4)
    start, far = np.array([3.0, 2.5, 0.3]), np.array([16.0, 6.0, 0.0])
    back = np.array([3.3, 2.2, 0.0])
    said = se2_compose(back, (0.2, -0.15, 0.08))          # where the trajectory puts it
    poses = np.array([start, far, said])
    first = [_scan(world, start, rng), _scan(world, far, rng)]
    loops = find_loops(poses, first + [_scan(world, back, rng)], 0.01)
    assert [(e.a, e.b) for e in loops] == [(0, 2)]
    err = relative(relative(start, back), loops[0].z)
    assert np.hypot(err[0], err[1]) < 0.03 and abs(err[2]) < 0.01, err
    assert np.hypot(*(relative(poses[0], poses[2]) - relative(start, back))[:2]) > 0.2
    for elsewhere in ((17.0, 9.5, 1.0), (8.0, 6.0, 0.0)):
        assert find_loops(poses, first + [_scan(world, elsewhere, rng)], 0.01) == []


def test_find_loops_refuses_a_return_that_a_featureless_corridor_cannot_place():
    # A loop must constrain every direction (module docstring): back in a straight corridor
    # whose ends lie beyond the laser's reach, the match along it is degenerate, so the 0.2 m
    # the trajectory drifted along the corridor is neither confirmed nor corrected: no loop.
    # (Without the degeneracy test, a mutation audit's mutant, the loop is taken.)
    walls = np.array([[[-100.0, 0.0], [100.0, 0.0]], [[-100.0, 2.0], [100.0, 2.0]]])
    world, rng = World(walls), np.random.default_rng(4)
    start, far, back = (np.array([0.0, 1.0, 0.0]), np.array([20.0, 1.0, 0.0]),
                        np.array([0.3, 1.0, 0.0]))
    poses = np.array([start, far, se2_compose(back, (0.2, 0.0, 0.0))])
    scans = [_scan(world, p, rng) for p in (start, far, back)]
    assert min(len(s) for s in scans) > 500
    assert find_loops(poses, scans, 0.01) == []
