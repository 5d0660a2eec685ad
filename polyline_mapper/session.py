"""
One mapping session: timed records in, the map out (ROS-free).

The live node, ``polyline-mapper replay``, the live demo and the benchmarks all map through
this class, so the live map equals the offline map of the same recording by construction.

Records (``formats.records``): ``Scan``, ``Transform``, ``Odometry`` and ``Skipped``. The node
converts messages to records and the map value back to messages; the offline tools read records
from ``recordings``. The session does, in this order:

1. **Check** each scan (``scan.check_scan``: REP 117 ranges, geometry); a bad one is counted
   under ``bad scan: <cause>`` (with scan matching from odometry or TF, one with no usable
   reading is posed first, as a scan not matched: ``_blind``).
2. **Pose** it (``PoseSource``): ``pose_source='tf'`` looks the scan's frame up in the fixed
   frame through the transform tree (``poses.TransformBuffer2D`` fed by /tf and /tf_static);
   ``'odom'`` uses the odometry pose composed with the laser mount (``mount``, or the scan
   frame's /tf_static mount when none is given), the map being in the odometry frame. Like a tf2
   message filter, a scan waits, in order, until pose data stamped at or after it has come (so
   its pose is interpolated, not held), or until its pose is known to be impossible; it gives up
   after ``wait`` seconds and is counted under ``no pose: <cause>``. ``'scan'`` needs no pose
   data at all: each scan's pose is predicted at constant velocity from the last two poses
   and refined by scan matching (the first scan sits at the fixed frame's origin).
3. **Convert** it to fixed-frame points (``scan_to_points``; ranges beyond
   ``IncrementalConfig.max_mapping_range`` are dropped with the invalid readings). When the
   scan's ``time_increment`` is set, each beam is placed at the pose interpolated at its own
   time (motion compensation: from TF / odometry, waiting for the pose data that covers the
   last beam; in scan mode, or when that data is missing, from the matched motion), relative
   to the pose at the stamp, so scan matching then moves the scan as one rigid body.
4. **Update** the incremental mapper once per ``update_every_n_scans`` posed scans (their
   points in one update); ``update_ms`` is the time of steps 3 and 4 together.
5. **Publish**: ``map_value()`` returns the one ``MapValue`` (segments, support, polylines, closed,
   frame, stamp, stats).

A session may start from a saved map (``load_map``: localization on it, scan matching on):
with ``SessionOptions.mapping`` False that map is returned unchanged and only the scans' poses
are found; with it True the scans are mapped into it.

Time comes from an injected clock. Offline (``clock=None``) it is *data time*: a scan arrives at
its own stamp and "now" is the newest pose data's stamp, so a replay gives the same map however
fast it runs. Live, the clock is wall time (``time.monotonic``): a scan waits at most ``wait``
seconds of real time for its pose.

Live, the worker runs one update per ``step(max_updates=1)`` and publishes in between, so a
slow update never starves the map or the diagnostics; when updates fall behind, the oldest
queued scans are shed (``max_queue``; counted under ``dropped: queue_full``) and the newest map
is always the one published.
"""

import bisect
from collections import Counter, deque
from dataclasses import dataclass, fields, replace
import itertools
import math
import threading
import time
from typing import Callable, Iterable, NamedTuple, Optional

import numpy as np

from .core.cleanup import seen_through
from .core.freespace import passing_beams
from .core.geometry import (config_of, in_box, is_number, is_real, se2_compose, se2_inverse,
                            wrap_angle)
from .core.grid import check_resolution, FreeSpaceGrid, GridMap
from .core.incremental import IncrementalConfig, IncrementalMapper
from .core.mapvalue import MapValue
from .core.polylines import MapGeometry
from .core.register import (CHORD_KNOTS, CHORD_MIN_EXTENT, DEFAULT_CHORD_KNOTS, match_scan,
                            odometry_covariance, RELOCALIZE_SHARE, scan_chords, ScanMatch,
                            search_after_gap, spread, transform)
from .formats.mapjson import stored_segments
from .formats.records import Odometry, PoseEstimate, Scan, Skipped, Transform
from .params import CORE_RANGES
from .poses import (estimate_lag, lag_costs, LAG_GRID, mount_quaternion, planar_edge, PlanarPose,
                    TransformBuffer2D, TransformLookupError)
from .scan import (beams_to_points, check_scan, scan_to_points, ScanError, sectors,
                   SELF_HIT_MOTION, SELF_HIT_TOLERANCE, SelfHits, usable_beams,
                   valid_ranges)

POSE_SOURCES = ('tf', 'odom', 'scan')
MAX_SCAN_SPAN = 1.0
"""Seconds the beams of one scan may span for motion compensation (longer: taken as bad)."""
MAX_MOTION_GAP = 1.0
"""Seconds between the last two poses beyond which their motion is not extrapolated."""
ODOM_GAP_STEPS = (3, 51)
"""``odom_gap_factor``: the intervals between odometry messages (odom mode) or between the
transforms of the odometry edge (tf mode: the lowest moving edge above the laser) that must be
seen before a gap is judged, and how many of the newest give the typical interval (their
median: stamps jittering by +-20 % of the period leave intervals within 1.4 x it, and one lost
message makes one of 1.6 x or more)."""
ODOM_GAP_MIN = 0.05
"""Seconds: a gap in the odometry shorter than this is never one (``_check_odom_gap``): at 1 kHz
/tf a 2 ms gap is twice the usual interval but hides no motion worth a scan (a live-node
audit: 43 of 100 scans refused so)."""
ODOM_SLOW = (0.4, 2.5, 11)
"""
(s, ratio, intervals): odometry whose typical interval (the median of its newest ``intervals``)
is this long and this many times the scans' typical interval is warned about, once
(``odom_rate``): each scan between two of its messages, and each of its beams, is posed by
interpolating across the interval, which spreads every change of the turn rate over it. A
simulated office drive turning in place at 1 rad/s under 10 Hz scans, matched: walls F1 1.00 with
odometry at 10 and 5 Hz, 0.96 at 2 Hz, 0.84 at 1 Hz (benchmarks/odom_rate.py). Converted
CARMEN logs and the simulator give one odometry message per scan: never warned.
"""
ODOM_JUMP = (1.0, 5.0)
"""Scan matching with odometry: (m, m/s). An odometry step (the base's motion between two matched
scans) that departs from the odometry's previous step, carried on at its pace, by more than the
first and than the second times the time between the scans is no motion but a jump
(``_odometry_jumped``): of the odometry frame under the robot (a driver that restarted, a wheel
that slipped) or of the robot with it (a recording played again). 5 m/s gained within one
scan (at 10 Hz: 50 m/s^2) is beyond any ground robot; 1 m is the relocalization's reach
(``RELOCALIZE``), which finds smaller jumps. Headings: ``ODOM_JUMP_TURN``."""
ODOM_JUMP_TURN = (0.5, 5.0)
"""Scan matching with odometry: (rad, rad/s). An odometry step into a pose near the odometry's
origin (``ODOM_RESET_REACH``) whose heading departs from the previous step's, carried on at its
pace, by more than the first and than the second times the time between the scans may be a
reset too (``_odometry_jumped``): a reset near the origin moves the robot less than
``ODOM_JUMP`` but turns it by its heading (a helper audit: 0.84 m and 83 deg, beyond the
matcher's heading search; the drive ended 20 m off). 5 rad/s gained within one scan (at 10 Hz:
50 rad/s^2) is beyond a ground robot's turn. Only near the origin: odometry at 5 Hz under 10 Hz
scans, interpolated across the simulated drives' 90 deg turns within a scan, steps so anywhere,
and re-anchored on the pace there the drive ended 35 m off (at most 0.82 m when not judged).
A turn the scan confirms (the odometry's match fits at least as well as the pace's) is motion:
not warned, nothing changed."""
ODOM_RESET_SHIFT = 0.3
"""Metres: a heading jump into a pose near the odometry's origin (``ODOM_JUMP_TURN``) is judged
only when the position is off the pace by more than this too. A helper audit: odometry at 5 Hz
under 10 Hz scans, interpolated across a simulated 90 deg turn within a scan, 0.3 m from where
the odometry started: 31 deg and 0.00 m off the pace, re-anchored on the pace twice, 1.8 m RMS
(0.016 m not judged); the reset it is for was 0.84 m off."""
ODOM_RESET_REACH = 1.0
"""Metres: an odometry pose within this of its origin, its heading within ``ODOM_JUMP_TURN[0]``
of the origin's, may have just been reset (``ODOM_JUMP_TURN``): the reach of the relocalization
(``RELOCALIZE``) that the smaller jumps are left to."""
ODOM_JUMP_MARGIN = 0.05
"""Share of a scan's points: at an odometry jump (``_odometry_jumped``) the odometry is kept
unless a pace's match puts this much more of the scan on the map than the odometry's, and the
last pace gives way to the pace without its turn, or to standing still, only by as much. In a
corridor every place along it fits nearly alike (the simulated corridors: 0.938 at the pace,
0.942 standing still, 0.25 m behind; a robot at 5 m/s and 5 Hz taken for a jump at 1.02 m off
its pace, the odometry right: 1.06 m off when the pace won by a hair)."""
TRAJECTORY_ROWS = 100000
"""Live (no ``keep_points``) with scan matching: the newest poses kept for ``map_value``."""
MOUNT_FRAME = '_laser_mount'
"""Odom mode with an explicit mount: the laser frame hung under the odometry child frame."""
MAX_SCAN_TIME_OFFSET = 10.0
"""Seconds ``scan_time_offset`` may move a scan's stamp, either way (more is another clock, not
a driver's latency: fix the clock)."""


ESTABLISHED_SUPPORT = 100.0
"""
Scan matching: map segments with at least this support (points) are established walls: a
correction they carry along a weakly constrained direction is taken whatever the odometry says
(``core.register.ESTABLISHED_SHARE``). The simulated office's segments: median 340, 10 % below
41; a person's arcs after a few scans: below 100.
"""
TURN_SLIP = 0.1
"""
Scan matching: metres of translation error per radian turned that the hold (``WEAK_SIGMAS``)
allows the odometry besides its error per metre (``odometry_covariance``): wheels slip in a
turn, as AMCL's ``alpha4`` (translation noise from rotation) models. Without it a turn in place
allowed no translation correction at all: on the drifted fr079 log (seed 0, AMD EPYC VM of
2026-11-27) the matcher held the along-corridor direction at the prediction during the turn at
the corridor's west end (scans 486-489), the heading took up the prediction's 5 cm error
(+3.5 -> -5.3 deg) and kept it (ATE 0.838 m); with 0.1 m/rad it stays within 2.3 deg and the
position within 0.27 m there.
"""
RECENT_SCANS = 12
"""
Scan matching: the last scans whose chords join G(t) as the map a new scan is matched to.
12 with 'median' knots against 6 with 'arc' (the defaults before 2026-11-30; drifted Radish
logs, seeds 0-14, benchmarks/README.md "Median knots and 12 recent scans"): RMS as the poses
stand Intel 0.365 -> 0.217 m, CSAIL 0.512 -> 0.267 m, ATE 0.123 -> 0.119 / 0.184 -> 0.164 m,
matching 10 % slower. 'median' with 6 lost a scan on Intel seed 2 (a 6.3 deg prediction
refused) and had the ATE worse on more seeds.
"""
KEYFRAME_STEP = (0.25, 0.15)
"""Scan matching: metres / radians a scan must be from the last keyframe to become one."""
MATCH_POINTS = 240
"""Scan matching: a scan with more points is matched (and kept as chords) with this many."""
DESKEW_ROUNDS = 3
"""
Scan matching with the beams placed from the matched motion (scan mode, or no pose data over the
sweep): matches again, at most this many times, with the beams placed from the motion the match
itself implies (the last matched pose to this one) while that moves the sweep's end by more than
``DESKEW_TOLERANCE``. With the motion of the interval before, a deskew error fed back: a
scan deskewed with too fast a turn matches turned back by about half the excess, the next
velocity then errs the other way, and so on (a simulated 5 Hz lidar swept over its whole period:
+-1.5 deg, sign alternating, scan after scan; turns in place lost a TurtleBot-like bag).
"""
DESKEW_TOLERANCE = (0.002, 0.002)
"""(m, rad) at the end of the sweep below which ``DESKEW_ROUNDS`` stop."""
MATCH_SIGMA = 0.03
"""Scan matching: the noise scale (m) used before the map has estimated its own sigma."""
MATCH_REACH = (0.5, 0.2)
"""
Scan matching: metres / radians from its prediction that a match reaches (``match_scan``'s
gate and heading turns). A pose estimate (``MappingSession.set_pose``) this close is matched
from; a wider one is searched for.
"""
RELOCALIZE = 1.0
"""
Scan matching: metres around the prediction searched when the map explains few of a scan's
points there (``match_scan``'s ``relocalize``): a wheel slip or a bump of up to this much can be
recovered (0.5 m passes the match gate; 0.8 m did not on the test's office drive: the scan was
mapped 0.8 m off, walls F1 0.49); the node then warns of the jump of ``map -> odom``. A slip
whose first match lands off the true pose but puts enough of the scan on the map is not
searched (0.8 m forward on ``benchmarks/slips.py``'s drives: mapped 0.7 m off).
"""
RELOCALIZE_DROP = (0.7, 10, 0.7)
"""
Scan matching: (factor, scans, cap). The relocalization search also starts when a scan's share
on the map falls below ``factor`` times the median share of the last ``scans`` matched scans,
up to ``cap`` (``match_scan``'s ``relocalize_share``; never below ``RELOCALIZE_SHARE``). A slip
is a sudden drop: on ``benchmarks/slips.py``'s drives an 0.8 m slip left 61 % of the scan on
the map, just above the fixed 60 %, and was mapped 0.7 m off; scans in clutter are low all
along (the drifted Intel and CSAIL logs, seed 0: 71 and 21 scans below 70 %, 30 and 7 below
60 %, 30 and 7 by this rule, so the search, 40-85 ms, stays as rare as before).
"""
LOST_WITHOUT_CHORDS = True
"""
Scan matching: while the session is lost (refused corrections, ``CONFIRM_JUMP``), scans are
matched to the map G(t) alone, not to the last scans' chords (``RecentChords``). Those were
kept before the loss and stay where the robot was then; dense and unfused (12 keyframes'
worth, every clutter edge), they give a scan predicted far off more places to lock onto. On
``benchmarks/slips.py``'s office drive (seed 7), a 1.5 m slip (beyond ``RELOCALIZE``) was
matched onto them 1 m off after 22 lost scans and mapped from there: poses up to 3.66 m off,
walls F1 0.29. Against the map alone the search relocalizes it 0.65 m off (F1 0.51), as on
the other drive; the drifted Radish logs are never lost, so they map as before. Where G(t)
has no segment near the scan the chords stay: lost before the mapper's first update (a gap in
the odometry at the fourth scan of ``benchmarks/odom_loss.py``'s sparse drive), the map alone
would be nothing, and no scan would ever be matched or mapped again.
"""
ANCHOR_SHARE = 0.5
"""
Localization on a saved map from odometry or TF (``SessionOptions.mapping`` False): a scan's
chords are kept for the next matches (``RecentChords``) only when its match puts at least this
share of its points on the map and the chords kept (``ScanMatch.share``); a scan not matched
keeps none. The map does not grow there, so chords of scans it does not explain can move with
the robot: a laser blocked all round (0.4 m on every beam) for 30 scans of the drifted office
drive (seed 1) was kept as chords at its predicted pose and the next blocked scans were matched
to them, with a 1-10 mm covariance while the odometry drove 8 m; seeing again 4 m away it was
matched into another room for good (blocked from scan 10, 20, ..., 310: 29 of 31 windows
1-14 m off from the 10th scan after the block on). Where the saved map lacks walls, scans
matched to the chords of the scans before them keep carrying the robot (the office map cut at
x = 10, 12 or 14 m, a third of the drive beyond: 0.5-0.8 cm RMS, as before); counting the
map's own segments alone (session 62's first attempt) left it 4 m off there. Scan mode has no
odometry to fall back on: unchanged.
"""
UNMATCHED_STREAK = (10, 1.0)
"""
Localization on a saved map from odometry or TF (``SessionOptions.mapping`` False): this many
scans in a row not matched, the newest at least this many seconds after the first (at 10 Hz the
11th), make the session not localized (``unmatched``, the ``not_localized`` warning, WARN on
/diagnostics) until a scan is found (``RECKONED_SEARCH``): their poses are the odometry's since
the last match (the laser blocked, the robot off the saved map). Scans searched for near a pose
estimate or after a gap are not counted (the session is lost then, and says so); a scan with
no reading to match (``_blind``: no return, or none in the mapping range) is. One or two
unmatched scans in clutter are not a loss (none on the office, Intel and CSAIL drives of
``benchmarks/covariance.py``). Scan mode has no odometry to follow: not counted there.
"""
RECKONED_SEARCH = 0.5
"""
Localization on a saved map, not localized (``UNMATCHED_STREAK``): only a search ends it. A
scan is searched for within ``POSE_ESTIMATE_SIGMAS`` standard deviations of the odometry's
error since the last match (``_reckon``; at least the match's own reach, at most ``GAP_REACH``
m and half a turn), at most once per this many seconds of scan stamps (a search costs 40-85
ms), and the pose found taken as after a gap (``GAP_SHARE`` of the scan on the map, no rival
place 0.5 m or 0.3 rad away); the other scans keep the odometry's pose, whatever their match
from it says (counted 'not localized'). After 3 s of scans that match nothing on the drifted
office drive the odometry was 0.7-1.5 m and 0.2-0.47 rad off (seed 1, 4 of 31 windows), beyond
the match's reach (``MATCH_REACH``, ``RELOCALIZE``): matched from there, the robot settled
0.8-12 m off for good.
"""
CONFIRM_JUMP = 3
"""
Scan matching: scans refused as too large a correction that, agreeing on it within
``CONFIRM_AGREE``, make it taken when a match from it puts ``RELOCALIZE_SHARE`` of the scan on
the map (a slip the relocalization search does not cover: a heading jump of 0.5 rad). From the
first refusal until a scan is matched the session is lost: no scan is mapped (nor kept as
chords), whatever its match says, so a wrong prediction never enters the map.
"""
CONFIRM_AGREE = (0.1, 0.05)
"""Scan matching: metres / radians within which refused corrections agree (``CONFIRM_JUMP``)."""
MATCH_DEGENERATE = {'tf': 0.02, 'odom': 0.02, 'scan': 0.005}
"""
Scan matching, per pose source: the eigenvalue share (``match_scan``'s ``degenerate``) below
which a direction keeps the prediction. Odometry or TF predicts each step to a few millimetres,
so only clearly constrained directions are corrected. A constant-velocity prediction (scan mode)
misses every start and stop: in a corridor whose only cue along its axis is a few door gaps it
would keep a robot that starts moving standing still (the simulated office, scan only: 2.7 m RMS
at 0.02, 2.5 cm at 0.005), so weak constraints are used there too. Scan mode's match of each
scan has no such guard since: ``SCAN_PRIOR`` weighs them; 0.005 holds for the searches after a
gap and the confirmation of a refused correction.
"""
GAP_SECONDS, GAP_FACTOR = MAX_MOTION_GAP, 3.0
"""
Scan mode: a scan more than this many seconds, and this many times the median interval of
the last posed scans, after the last posed scan comes after a *gap* (dropped or unusable
scans): the constant-velocity prediction (extrapolated at most ``MAX_MOTION_GAP``) cannot be
trusted, and the pose is searched for wider (``search_after_gap``). A 2 s gap on the office
drive (1 m/s, 1 rad/s) left the robot 0.7 m and 1.4 rad from the last pose: beyond the match's
gate and heading turns; the track was lost (11 m RMS, walls F1 0.33). Shorter gaps are
matched from the prediction, as every scan.
"""
SCAN_MOTION_SHARES = (0.0, 0.5)
"""
Scan mode: besides the constant-velocity prediction, the poses moved on by these shares of its
motion are tried as the match's start (``match_scan``'s ``starts``): a robot that stopped, or
slowed down in a turn. On fr079 (4.3 Hz, turns up to 17 deg a scan), against the corrected
poses, the constant-velocity heading is more than 0.2 rad off on 46 of 4789 scans (at most 0.53
rad), beyond the matcher's heading search (+-0.2 rad); the pose moved on by half the motion on
4 (0.23 rad), the last pose itself on 13 (0.31 rad). One such scan (678, 0.24 rad off) was
matched onto the wrong wall and the replay was lost (13.6 m ATE).
"""
MATCH_SEEN_THROUGH = True
"""
Scan matching from odometry or TF: the young map segments (support below
``ESTABLISHED_SUPPORT``) and the last scans' chords that the scan's beams pass through at the
predicted pose are left out of its match (``core.cleanup.seen_through``, the mapper's own test
for the short segments it clears: at least 3 beams, crossing the piece at >= 20 deg and ending
beyond it by more than kappa sigma plus 3 % of the range). What the beams see through is not
there now: a person walking ahead of the robot left arcs in the map and in the last scans'
chords, and the new scan's points on the person pulled each match back along a corridor onto
them. Established walls always take part (a loop's return onto older ground: with a drifted
pose the beams may pass them). On the simulated office with a person walking ahead (true
odometry, drive seeds 1-8, three evidence settings: 24 drives) the RMS error falls from 0.099
to 0.081 m on average; on the drifted Radish logs (issue 19's model, seeds 0-4, an AMD EPYC VM)
the ATE from 0.154 to 0.100 m (Intel; largest 0.285 -> 0.122) and 0.195 to 0.165 m (CSAIL),
fr079 0.086 -> 0.085 m. Scan mode (a constant-velocity prediction, decimetres off) does not.
"""
SCAN_PRIOR = (0.05, 0.05)
"""
Scan mode: the constant-velocity prediction's error is taken as a Gaussian prior on the match
(``match_scan``'s ``prediction_prior``, with no hard degeneracy guard): standard deviations of
the motion since the last scan on each axis and in heading (the robot may have stopped), at
least these (m, rad). The guard held a direction whose information was below 0.005 of the
strongest at the prediction, so a weak cue flipped between held and used on a threshold: where
the simulated office's robot stops in the corridor to turn (seed 1, scans 785-787) the door
gaps were used with numpy 2.4 (largest error 0.04 m) and not with numpy 1.26 (0.17 m); with the
prior 0.06 m with either. Relocalization within the first gate (``match_scan``'s
``relocalize_near``) comes with it: a turn the prediction misses left fr079's scans-alone replay
in a wrong basin at scan 1825 (50 % of the points on the map; 89 % where Gauss-Newton from the
true motion goes) and 1.4-2.0 m ATE over five runs on an AMD EPYC VM.
"""
GAP_SPEED, GAP_TURN_RATE, GAP_REACH = 1.0, 1.0, 3.0
"""
Scan mode, after a gap: the search covers the positions within the gap's length times this
speed (m/s) of the prediction and the headings within its length times this turn rate (rad/s),
at most half a turn; the speeds before the gap when higher (a corridor looks alike turned by
half a turn: a heading the robot cannot have is not tried). A gap whose reach exceeds
``GAP_REACH`` metres is not searched: the session is lost for good.
"""
GAP_NEAR = (0.5, 0.35)
"""
Scan mode, after a gap (not near a pose estimate): a pose found within these (m, rad) of the
prediction, where a match from the prediction would take it (``match_scan``'s ``max_shift``,
``max_turn``), needs only ``RELOCALIZE_SHARE`` of the scans on the map, as that match would;
``GAP_SHARE`` is for a pose farther away. On fr079 (scans alone) a gap of 1.3 s at 556 s, with
the robot 0.06 m and 2 deg on, was not bridged: 72-80 % of the scans after it lay on the map
(new ground in view), under the 88 % of ``GAP_SHARE``, and the rest of the log (2267 scans)
was not mapped.
"""
GAP_KEYFRAMES, GAP_POINTS = 8, 120
"""
Scan mode, after a gap: the first keyframes of the scans tracked since, and the points of
each, searched on the map together (a corridor seen from one place fits anywhere along it;
with its end or a door in sight it fits once).
"""
POSE_ESTIMATE_SIGMAS = 3.0
"""
A pose estimate (``MappingSession.set_pose``; the node's ``initialpose``, RViz's "2D Pose
Estimate") is searched within this many standard deviations of its covariance, as a scan after
a gap is (at most ``GAP_REACH`` metres and half a turn).
"""
START_CHECK = (10, 0.3)
"""
Localization on a saved map (``load_map``): after the first this-many scans placed (from the
start, a reset or a pose estimate), when the median share of their beams that pass through the
saved map's segments (``core.freespace.passing_beams``) exceeds the second number, warn once
(``wrong_start``): the scans were matched onto a wrong place. Measured on the Intel and CSAIL
logs (``benchmarks/pose_estimate.py``, first 10 scans): at the right place 1 % and 18 % of the
beams pass through the saved walls (CSAIL's walls have gaps), at a wrong place where every scan
still matched (a start 2.5 m and 0.6 rad off) 40 % and 49 % (2026-12-01, since scans put under
half on the map keep no chords: 3 % and 10 % at the right place, 33 % and 41 % at the wrong
one; Intel's now near the bar). Not caught: the simulated office started 1.7 m off, matched 0.8 m
off along its walls (11 %).
"""
GAP_SHARE, GAP_RIVAL = 0.9, 0.1
"""
Scan mode, after a gap: a pose found is taken when it puts at least ``GAP_SHARE`` times the
median share of the last matched scans (and ``RELOCALIZE_SHARE``) of the points on the map,
and no other refined candidate more than 0.5 m or 0.3 rad away comes within ``GAP_RIVAL`` of
its share (a corridor seen without its ends fits anywhere along it, and turned by half a
turn). Else the session is lost: no scan is mapped until one is found so.
"""
ESTIMATE_PRIOR_MARGIN = 4.0
"""
Near a pose estimate, rival poses that explain the scans alike (``GAP_RIVAL``) are told apart
by the estimate itself: the one nearest it is taken when every other lies at least this much
farther in squared standard deviations of the estimate (``POSE_ESTIMATE_SIGMAS``: the window
is three), i.e. the estimate finds it more than e^2 = 7.4 times as likely. An audit: RViz's
default estimate (0.5 m, 0.26 rad) at the true pose of the simulated office's corridor, with the
robot localized, found the true pose and one 1.5 m along the corridor alike, and scan matching
gave up for good (no later scan used). An estimate half-way between them stays ambiguous.
"""


def _nearest_estimate(alike: list, center: np.ndarray, window: tuple,
                      tracked: Optional[np.ndarray] = None) -> tuple:
    """
    Of matches that explain the scans alike, the one a pose estimate prefers; (it, rivals left).

    ``center``: the estimate's laser pose, ``window``: its ``POSE_ESTIMATE_SIGMAS`` standard
    deviations (m, rad). The match nearest ``center`` in those deviations is taken with no
    rivals left when every other lies ``ESTIMATE_PRIOR_MARGIN`` farther. Else, ``tracked``:
    where the scans matched before the estimate lead this scan (the session was localized),
    when that nearest match lies within ``GAP_NEAR`` of it: the estimate and the tracking
    agree. (A tracked pose that is not the estimate's nearest never wins: a session tracked
    confidently 1.5 m off in the corridor, given a right estimate 0.6-0.9 m off the truth,
    was locked at the wrong place by the first version of this rule, an audit.) Else the
    first match and the others, unchanged.
    """
    sd = np.maximum(np.asarray(window, dtype=np.float64) / POSE_ESTIMATE_SIGMAS, 1e-3)
    d2 = np.array([(math.hypot(*(m.pose[:2] - center[:2])) / sd[0]) ** 2
                   + (wrap_angle(m.pose[2] - center[2]) / sd[1]) ** 2 for m in alike])
    k = int(np.argmin(d2))
    if (np.delete(d2, k) >= d2[k] + ESTIMATE_PRIOR_MARGIN).all():
        return alike[k], []
    m = alike[k]
    if tracked is not None and (math.hypot(*(m.pose[:2] - tracked[:2])) <= GAP_NEAR[0]
                                and abs(wrap_angle(m.pose[2] - tracked[2])) <= GAP_NEAR[1]):
        return m, []
    return alike[0], alike[1:]


def _compose(a, b) -> np.ndarray:
    """
    Return ``a`` composed with ``b``: ``se2_compose``, faster for single poses (a few per scan).

    The same numbers, bit for bit: np.cos / np.sin and the products and sums of ``se2_compose``,
    in its order, on numpy scalars instead of 0-d arrays (9 us -> 2 us per call).
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != (3,) or b.shape != (3,):
        return se2_compose(a, b)
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def _inverse(a) -> np.ndarray:
    """Return the inverse of ``a``: ``se2_inverse``, faster for a single pose (as ``_compose``)."""
    a = np.asarray(a, dtype=float)
    if a.shape != (3,):
        return se2_inverse(a)
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


def motion_velocity(motion, stamp: float) -> Optional[np.ndarray]:
    """
    Return the motion per second (body frame, (3,)) of ``motion`` usable at ``stamp``, or None.

    ``motion``: the last two (stamp, (x, y, yaw)) poses; None when fewer, more than
    ``MAX_MOTION_GAP`` apart, or ``stamp`` is not within ``MAX_MOTION_GAP`` after the last.
    """
    if len(motion) < 2:
        return None
    (t0, p0), (t1, p1) = motion
    if not (0 < t1 - t0 <= MAX_MOTION_GAP and 0 <= stamp - t1 <= MAX_MOTION_GAP):
        return None
    step = _compose(_inverse(p0), p1)
    step[2] = wrap_angle(step[2])
    return step / (t1 - t0)


def _one_laser(first: Optional[str], frame: str, says: Callable[[str], str]) -> str:
    """
    Return the laser frame a pose source follows: ``first``, or ``frame`` when there is none.

    Another frame raises TransformLookupError('laser_frame', ...) with ``says(first)``.
    """
    if first is not None and frame != first:
        raise TransformLookupError('laser_frame', f'scan in frame {frame!r}, but {says(first)}')
    return frame


def _affine(x: float, y: float, yaw: float, flip: bool) -> np.ndarray:
    """Return a planar pose as a 2D affine map (3, 3); an upside-down frame's mirrors its y."""
    c, s = math.cos(yaw), math.sin(yaw)
    m = -1.0 if flip else 1.0
    return np.array([[c, -s * m, x], [s, c * m, y], [0.0, 0.0, 1.0]])


SELF_HIT_FRAMES = 8
"""Most lasers (frame ids) whose readings ``_check_self_hits`` follows at once."""


class _Deskew:
    """
    A scan's beams placed from a constant motion over its sweep, and placed again from a match.

    ``last``: the last matched (stamp, laser pose); ``velocity``: the motion per second (body
    frame) the beams are first placed with; ``times``, ``span``: each beam's seconds after the
    stamp and the sweep's (``beam_span``); ``angles``, ``limits``: the beams' angles (laser
    frame) and the mapping range limits (lowest, highest). ``propose(pose)`` returns the
    scan's points placed with the motion from ``last`` to ``pose`` (a match of the scan at its
    stamp), or None when that moves the sweep's end by less than ``DESKEW_TOLERANCE`` (or
    cannot be used: ``motion_velocity``); ``accept()`` keeps the proposal; ``local`` gives the
    points of the motion kept.
    """

    def __init__(self, scan: Scan, last: tuple, velocity: np.ndarray, times: np.ndarray,
                 span: float, angles: np.ndarray, limits: tuple):
        self.stamp, self.last = float(scan.stamp), last
        self.times, self.span = times, span         # each beam's seconds, the sweep's
        self.angles, self.limits = angles, limits   # the beams' angles, the range limits
        self.velocity = np.asarray(velocity, dtype=np.float64)
        self.motion = self._motion(self.velocity)
        self._proposal = None
        self._scan = scan

    def _motion(self, velocity: np.ndarray) -> np.ndarray:
        """Return each beam's laser pose relative to the stamp's, (B, 3), at ``velocity``."""
        return sweep_motion(self.times, self.span,
                            velocity[None] * np.array([[0.5 * self.span], [self.span]]))

    def _points(self, motion: np.ndarray) -> np.ndarray:
        """Return the scan's points (laser frame at its stamp), cast as ``motion`` says."""
        return beam_points(self._scan.ranges, self.angles, motion, *self.limits)

    def propose(self, pose) -> Optional[np.ndarray]:
        """Return the scan's points with the motion ``pose`` implies, or None."""
        v = motion_velocity([self.last, (self.stamp, np.asarray(pose, dtype=np.float64))],
                            self.stamp)
        if v is None:
            return None
        d = np.abs(v - self.velocity) * self.span
        if math.hypot(d[0], d[1]) <= DESKEW_TOLERANCE[0] and d[2] <= DESKEW_TOLERANCE[1]:
            return None
        self._proposal = v
        return self._points(self._motion(v))

    def accept(self) -> None:
        """Keep the last proposal's motion."""
        self.velocity = self._proposal
        self.motion = self._motion(self.velocity)

    def local(self) -> np.ndarray:
        """Return the scan's points (laser frame at its stamp) with the motion kept."""
        return self._points(self.motion)


def sweep_motion(times: np.ndarray, span: float, rel: np.ndarray) -> np.ndarray:
    """
    Return each beam's laser pose relative to the stamp's, (B, 3), over a sweep of ``span`` s.

    ``rel`` (2, 3): the laser's pose at the sweep's middle and end relative to its pose at the
    stamp; ``times`` (B,): each beam's seconds after the stamp. Interpolated linearly between
    the start, the middle and the end (headings unwrapped).
    """
    knots = np.array([0.0, 0.5 * span, span])
    rel = np.vstack([np.zeros(3), rel])
    rel[:, 2] = np.unwrap(wrap_angle(rel[:, 2]))
    return np.column_stack([np.interp(times, knots, rel[:, k]) for k in range(3)])


def extrapolate(motion, stamp: float) -> np.ndarray:
    """
    Return the last pose of ``motion`` moved on at its velocity to ``stamp``: constant velocity.

    At most ``MAX_MOTION_GAP`` of motion is added; the last pose itself without a velocity
    (``motion_velocity``) or for a ``stamp`` before it.
    """
    t1, last = motion[-1]
    velocity = motion_velocity(motion, t1)
    elapsed = stamp - t1
    return last if velocity is None or elapsed < 0 else _compose(
        last, velocity * min(elapsed, MAX_MOTION_GAP))


def _median(values) -> float:
    """
    Return ``float(np.median(values))`` of a short sequence of floats, without numpy's overhead.

    The same number: the middle value, or the two middle ones' sum halved (NaN: numpy's).

    >>> _median([0.5, 0.1, 0.3, 0.2]), _median((3.0, 1.0, 2.0))
    (0.25, 2.0)
    """
    s = sorted(values)
    n = len(s)
    if not n or any(v != v for v in s):
        return float(np.median(values))
    h = n // 2
    return float(s[h]) if n % 2 else float((s[h - 1] + s[h]) / 2)


def far_enough(last: Optional[np.ndarray], pose: np.ndarray) -> bool:
    """Return whether ``pose`` is ``KEYFRAME_STEP`` or more from keyframe ``last`` (or none)."""
    if last is None:
        return True
    step = _compose(_inverse(last), pose)
    return not (math.hypot(step[0], step[1]) < KEYFRAME_STEP[0]
                and abs(wrap_angle(step[2])) < KEYFRAME_STEP[1])


FOREGROUND_DEPTH = 0.3
"""
Scan matching: metres by which the readings on both sides of a run must lie farther from the
laser than the run's ends for the run to stand free (``RecentChords``): a person, a post. A run
of a wall that ends where its readings thin out (at range, or at grazing incidence) has a
neighbour about as far on at least one side.
"""


CHORD_CONFIRMATIONS, CHORD_CONFIRM = 1, 0.06
"""
Scan matching: a person-sized chord (``RecentChords``) stops being transient once this many
other kept keyframes have a chord end or middle within this many metres of its middle: it
stood still while the robot moved (a post). A person walking ahead has moved on. With 2
instead of 1, the drifted CSAIL log (seed 2) kept the odometry along a corridor whose only cue
along it was such a post: 0.146 -> 0.304 m ATE; with 1 it maps as before.
"""


def _near(points: np.ndarray, frame: list) -> np.ndarray:
    """
    Return which ``points`` lie within ``CHORD_CONFIRM`` of a keyframe's chords: (M,) bool.

    Of an end or the middle of one of ``frame``'s chords (a ``RecentChords`` keyframe); the
    keyframe's KD-tree is built on first use.
    """
    if frame[3] is None:
        from scipy.spatial import cKDTree
        chords = frame[0]
        frame[3] = cKDTree(np.concatenate([chords[:, 0], chords[:, 1], chords.mean(axis=1)]))
    return np.isfinite(frame[3].query(points, k=1, distance_upper_bound=CHORD_CONFIRM)[0])


class RecentChords:
    """
    The chords of the last keyframes (fixed frame): the map's newest edge for scan matching.

    Chords along a run of readings that stands free (``FOREGROUND_DEPTH``) and is narrower
    than ``register.CHORD_MIN_EXTENT`` may be something that moves: a person. Until another
    keyframe confirms them (``CHORD_CONFIRMATIONS``), ``transient`` marks them for
    ``match_scan``, which holds a weakly constrained direction at the prediction when they
    carry it (``register.TRANSIENT_SHARE``): a person walking ahead along a corridor no longer
    pulls the matches back along it. The chords are matched to all the same.
    """

    def __init__(self, size: int, knots: str = DEFAULT_CHORD_KNOTS):
        self.knots = knots
        """``register.scan_chords``'s knot rule (``SessionOptions.chord_knots``)."""
        self._frames = deque(maxlen=size)
        """Per keyframe: [chords (K, 2, 2), person-sized (K,), other keyframes confirming (K,)
        (counted up to ``CHORD_CONFIRMATIONS``), KD-tree of the chords' ends and middles or
        None (``_near``)]."""

    def __len__(self) -> int:
        return len(self._frames)

    def clear(self) -> None:
        """Forget every keyframe."""
        self._frames.clear()

    def add(self, world: np.ndarray, origin: np.ndarray) -> None:
        """Keep a keyframe's chords: its points (fixed frame, beam order), laser at ``origin``."""
        chords, extent, first, last = scan_chords(world, extents=True, knots=self.knots)
        r = np.hypot(*(world - np.asarray(origin, dtype=np.float64)[:2]).T)
        n = len(world)
        before = np.where(first > 0, r[np.maximum(first - 1, 0)], -np.inf)
        after = np.where(last < n - 1, r[np.minimum(last + 1, n - 1)], -np.inf)
        alone = (before > r[first] + FOREGROUND_DEPTH) & (after > r[last] + FOREGROUND_DEPTH)
        short = (extent < CHORD_MIN_EXTENT) & alone
        new = [chords, short, np.zeros(len(chords), dtype=np.intp), None]
        for f in self._frames:
            if not len(f[0]) or not len(chords):
                continue
            wait = new[1] & (new[2] < CHORD_CONFIRMATIONS)
            if wait.any():
                new[2][wait] += _near(chords[wait].mean(axis=1), f)
            wait = f[1] & (f[2] < CHORD_CONFIRMATIONS)
            if wait.any():
                f[2][wait] += _near(f[0][wait].mean(axis=1), new)
        self._frames.append(new)

    def chords(self) -> np.ndarray:
        """Return the chords, oldest keyframe first: (K, 2, 2)."""
        if not self._frames:
            return np.zeros((0, 2, 2))
        return np.concatenate([f[0] for f in self._frames])

    def transient(self) -> np.ndarray:
        """Return which of ``chords()`` lie along an unconfirmed person-sized run: (K,) bool."""
        if not self._frames:
            return np.zeros(0, dtype=bool)
        return np.concatenate([f[1] & (f[2] < CHORD_CONFIRMATIONS) for f in self._frames])


class GapTrack:
    """
    Scan mode, after a gap: the scans tracked against each other until they are found on the map.

    Poses are in the frame of the first scan after the gap (``motion``); ``center`` and
    ``window``: where that scan is predicted on the map and how far (m, rad) it may be from
    there. Keyframes (``KEYFRAME_STEP``) keep their chords (the next scans are matched to the
    last ``RECENT_SCANS``) and ``GAP_POINTS`` of their points (the first ``GAP_KEYFRAMES``):
    what is searched on the map.
    """

    def __init__(self, since: float, first: float, center: np.ndarray, window: tuple,
                 estimate: np.ndarray = None, knots: str = DEFAULT_CHORD_KNOTS):
        self.knots = knots
        """``register.scan_chords``'s knot rule (``SessionOptions.chord_knots``)."""
        self.since = float(since)
        """Stamp (s) of the last posed scan before the gap."""
        self.estimate = estimate
        """The robot base pose (x, y, yaw) of a pose estimate (``set_pose``) searched for around
        ``center``; None after a gap."""
        self.tracked = None
        """Near an estimate given while localized: where the scans matched before it put the
        first scan (``_nearest_estimate``); else None."""
        self.first = float(first)
        """Stamp (s) of the first scan after it."""
        self.center = np.asarray(center, dtype=np.float64).copy()
        self.window = (float(window[0]), float(window[1]))
        self.motion = deque(maxlen=2)
        self.chords = deque(maxlen=RECENT_SCANS)
        self.keys = []
        self.key_pose = None
        self.warned = 0
        """Warnings given: 1 lost, 2 given up."""
        self.given = None
        """The odometry (or TF) pose of the last tracked scan, when there is one."""
        self.why = ''
        self.paused = True
        """Whether the scans paused before it (else they came, and did not match)."""
        self.reset = False
        """Whether the odometry came back near its origin after the gap (a driver restart)."""

    def add(self, stamp: float, local: np.ndarray, sigma: float, degenerate: float,
            given: np.ndarray = None) -> bool:
        """
        Track one scan ((N, 2), laser frame); return whether it became a keyframe.

        ``given``: its pose by odometry or TF (their frame): the track then predicts each scan
        by the odometry's motion since the last one (a log of scans 0.5 m apart is not
        followed at constant velocity); None (scan mode): at constant velocity.
        """
        pose = np.zeros(3)
        if self.motion:
            t1 = self.motion[-1][0]
            if given is not None and self.given is not None:
                step = _compose(_inverse(self.given), np.asarray(given, dtype=np.float64))
                pose = _compose(self.motion[-1][1], step)
            else:
                pose = extrapolate(self.motion, stamp)
            if self.chords:
                m = match_scan(local, pose, np.concatenate(list(self.chords)), sigma,
                               degenerate=degenerate)
                if m.ok:
                    pose = m.pose
            if stamp <= t1:
                self.motion.clear()
        self.motion.append((stamp, pose))
        self.given = None if given is None else np.asarray(given, dtype=np.float64).copy()
        if not far_enough(self.key_pose, pose):
            return False
        world = transform(local, pose)
        self.chords.append(scan_chords(world, knots=self.knots))
        self.keys.append(spread(world, GAP_POINTS))
        self.key_pose = pose
        return True

    @property
    def final(self) -> bool:
        """Whether the scans are not searched again (``GAP_KEYFRAMES``, ``GAP_REACH``)."""
        return len(self.keys) >= GAP_KEYFRAMES or self.window[0] > GAP_REACH

    def points(self) -> np.ndarray:
        """Return the keyframes' points, (N, 2) in the first scan's frame."""
        return np.concatenate(list(self.keys))


def beam_span(scan: Scan) -> float:
    """Return the seconds from the scan's first beam to its last (0: no usable time_increment)."""
    try:
        ti = float(scan.time_increment)
    except (TypeError, ValueError):
        return 0.0
    n = len(scan.ranges)
    if isinstance(scan.time_increment, bool) or not (math.isfinite(ti) and ti > 0) or n < 2:
        return 0.0
    span = ti * (n - 1)
    return span if span <= MAX_SCAN_SPAN else 0.0


def beam_points(ranges, angles, motion: np.ndarray, range_min: float,
                range_max: float) -> np.ndarray:
    """
    Return the usable readings as points in the frame of the laser at the scan's stamp.

    ``motion`` (B, 3): each beam's laser pose (x, y, yaw; m, rad) relative to that frame, so
    beam i is cast from where the laser was when it took it. Returns (M, 2) metres, M <= B.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    ok = valid_ranges(r, range_min, range_max) & np.isfinite(a)
    p = motion[ok]
    ang = a[ok] + p[:, 2]
    return np.stack([p[:, 0] + r[ok] * np.cos(ang), p[:, 1] + r[ok] * np.sin(ang)], axis=1)


@dataclass
class _Blind(Scan):
    """A scan with no usable reading, queued to be posed as not matched (``_blind``)."""

    why: str = ''
    """Why it is skipped then (``check_scan``'s words)."""


class SessionError(ValueError):
    """A problem that makes the whole session meaningless (not one skipped record)."""


@dataclass
class SessionOptions:
    """How scans get their poses and are grouped into updates."""

    pose_source: str = 'tf'
    """'tf', 'odom' or 'scan' (no pose data: constant velocity refined by scan matching; sets
    ``scan_matching``)."""
    fixed_frame: Optional[str] = None
    """Map frame. tf: default 'map' when the scan frame's tree has it, else its root (with
    ``scan_matching``: 'map' above that root); odom: the odometry frame (odometry in another
    frame is skipped and counted); scan: default 'map'."""
    tolerance: float = 0.1
    """Seconds a stamp may lie outside the stored transforms and still use the nearest."""
    wait: float = 0.5
    """Seconds (of the session's clock) a scan waits for a pose that may still come."""
    mount: Optional[tuple] = None
    """(x, y, yaw) metres / radians of the laser in the odometry child frame (odom mode). When
    given it is used whatever the scan's frame and /tf_static say; when not, the scan frame's
    mount comes from /tf_static."""
    mount_upside_down: bool = False
    """The ``mount`` laser is rolled 180 degrees (its beams sweep clockwise seen from above)."""
    cache_seconds: float = 30.0
    """Seconds of transform (or odometry) history kept per frame."""
    every: int = 1
    """Use every N-th scan (counted over all scans received)."""
    update_every_n_scans: int = 1
    """Posed scans whose points go into one update."""
    max_waiting: int = 200
    """Scans that may wait for their pose; beyond, the oldest gives up waiting."""
    max_queue: Optional[int] = None
    """Live load shedding: posed scans that may wait for an update; beyond, the oldest are
    dropped (counted). None: never shed (offline)."""
    max_latency: Optional[float] = None
    """Live load shedding: seconds (of the clock) a posed scan may wait for its update; older
    ones are dropped (counted), keeping the newest group, so the map stays current when
    updates are slower than the scans. None: never (offline)."""
    keep_points: bool = False
    """Keep every mapped point (offline: for map metrics and plots). Memory grows with them."""
    mapping: bool = True
    """False: the map is never changed: the scans are only registered (points, counts and,
    with scan matching, their poses), so an empty map stays empty and a loaded one
    (``MappingSession.load_map``) stays exactly as loaded: localization only."""
    scan_matching: bool = False
    """Refine each scan's pose against the map built so far (``core.register.match_scan``),
    starting from the odometry / TF pose corrected as the last match was: the map is then as
    consistent as the scans, not as the odometry. Off: the poses are used as given."""
    chord_knots: str = DEFAULT_CHORD_KNOTS
    """Scan matching: how the knots of the last scans' chords (``register.scan_chords``) are
    placed along each scan: 'median' every 0.15 m of an arc whose steps are medians of their
    neighbours'; 'arc' every 0.15 m of the raw arc, whose knots are readings that noise
    displaced along the sweep, so every match turns the same way: -0.10 deg a match on the
    Intel log, 1.9-4.9 deg over a 3-minute drive of a lidar whose noise grows with the range
    (benchmarks/cheap_lidar.py). 'arc' was the default before 2026-11-30."""
    odom_frame: Optional[str] = None
    """Scan matching into ``fixed_frame``: the odometry frame, whose correction fixed frame ->
    it the session computes (the node broadcasts it). None: the first odometry's frame (odom
    mode) or the root of the scan frame's TF tree (tf mode); set it when that root is not the
    odometry frame (a 'world' above each robot's 'robotN/odom')."""
    odom_gap_factor: float = 1.5
    """A scan whose stamp falls between two odometry messages (odom mode) or two transforms of
    the odometry edge (tf mode: the lowest moving transform above the laser, odom ->
    base_link) more than this many times the odometry's typical interval apart is skipped
    (``no pose: odom_gap``) instead of given a pose interpolated across the gap, where a lost
    message hides the motion (a turn begun or ended in it). One lost message doubles an
    interval; 0 interpolates across any gap, as tf2 does."""
    scan_time_offset: float = 0.0
    """Seconds added to every scan's stamp as it arrives, before anything reads it (its pose,
    its beams' times, the trajectory), as a laser driver's time offset does: a driver that
    stamps its scans 0.1 s late (when sent, not at the first beam) needs -0.1. With scan
    matching the session estimates the lag and warns (``scan_clock``) with the value to set."""
    grid_resolution: Optional[float] = 0.05
    """Cell size (m) of the planner map (``occupancy``): the beams of every mapped scan are
    traced into a free-space grid. None: no grid (and no cost)."""

    def __post_init__(self):
        """Reject values that cannot work, naming the field."""
        if self.chord_knots not in CHORD_KNOTS:
            raise ValueError(f'chord_knots must be one of {CHORD_KNOTS}, got {self.chord_knots!r}')
        if self.pose_source not in POSE_SOURCES:
            raise ValueError(f'pose_source must be tf, odom or scan, got {self.pose_source!r}')
        if self.pose_source == 'scan':
            self.scan_matching = True       # the scans are the only source of poses
        for name in ('every', 'update_every_n_scans', 'max_waiting'):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f'{name} must be an integer >= 1, got {v!r}')
        if self.max_queue is not None and (int(self.max_queue) != self.max_queue
                                           or self.max_queue < self.update_every_n_scans):
            raise ValueError(f'max_queue must be an integer >= update_every_n_scans, got '
                             f'{self.max_queue!r}')
        if self.max_latency is not None and not (math.isfinite(self.max_latency)
                                                 and self.max_latency > 0):
            raise ValueError(f'max_latency must be a finite number > 0 or None, got '
                             f'{self.max_latency!r}')
        for name in ('tolerance', 'wait', 'cache_seconds', 'odom_gap_factor'):
            v = getattr(self, name)
            if not (is_number(v) and v >= 0):
                raise ValueError(f'{name} must be a finite number >= 0, got {v!r}')
        v = self.scan_time_offset
        if not (is_number(v) and abs(v) <= MAX_SCAN_TIME_OFFSET):
            raise ValueError(f'scan_time_offset must be a number of seconds within '
                             f'+-{MAX_SCAN_TIME_OFFSET:g}, got {v!r}')
        if self.fixed_frame is not None and not str(self.fixed_frame).strip():
            raise ValueError('fixed_frame must be a frame name, got an empty string')
        if self.grid_resolution is not None:
            check_resolution(self.grid_resolution)
        if self.mount is not None:
            m = np.asarray(self.mount, dtype=float)
            if m.shape != (3,) or not np.isfinite(m).all():
                raise ValueError(f'mount must be 3 finite numbers (x, y, yaw), got {self.mount}')


class RecordSkipped(ValueError):
    """A record that cannot be used; ``cause`` names the reason in one word."""

    def __init__(self, cause: str, reason: str):
        super().__init__(reason)
        self.cause = cause


SCAN_TREE_FRAMES = 256
"""Scan mode: frames whose parent edge is kept (``PoseSource.scan_root``); junk frame names on
/tf cannot grow it beyond this."""

TIME_JUMP_BACK = 1.0
"""Seconds one transform edge's (or the odometry's) own stamps may step back before that is
taken as the clock jumping back (a bag or simulation restarted) and the stored dynamic transforms
are dropped, as tf2_ros does on a jump of ROS time. A smaller step is out-of-order data
(``stamp_order``). Before, only a step beyond the cache (``transform_cache``, 30 s) was a jump:
a bag restarted 14 s in was placed on the old run's transforms (the simulated office: 244
segments against 27)."""


class PoseSource:
    """
    The transforms (and odometry) seen so far; the laser pose of a scan at its stamp.

    Not thread-safe by itself: the session holds its lock around ``add`` and ``pose``.
    """

    def __init__(self, options: SessionOptions):
        self.options = options
        self.buffer = TransformBuffer2D(options.cache_seconds)
        self.fixed_frame = options.fixed_frame
        self.localizer = bool(options.scan_matching and options.fixed_frame)
        """Scan matching into a given fixed frame (or, in tf mode, into 'map' when the tree has
        no map frame: set at the first posed scan): the session publishes that frame (map ->
        odom), so the poses are looked up in ``odom_frame`` and transforms from the fixed frame
        (its own map -> odom, read back from /tf) are never a pose source."""
        self.odom_frame = (options.odom_frame or None) if self.localizer else None
        """The frame the poses are looked up in: the fixed frame, or (``localizer``) the
        odometry frame: ``options.odom_frame``, else the first odometry's frame (odom mode) /
        the root of the scan frame's tree (tf mode)."""
        self.base_frame = None
        """The robot base: the odometry's child frame (odom mode), or in the localizer's tf mode
        the frame under ``odom_frame`` on the scan frame's chain."""
        self.latest = -math.inf
        """Newest stamp of dynamic pose data (transforms or odometry), seconds."""
        self._last_lookup = None
        """((target, source, stamp, tolerance), PlanarPose) of the last ``_lookup``, until the
        buffer changes: a scan's robot pose and base pose are often the same lookup."""
        self._parents = {}
        self._static = set()
        """Frames whose edge to their parent is static (a mount)."""
        self._under_fixed = set()           # localizer: children of ignored fixed-frame edges
        self._held = {}                     # their warnings, until the robot's chain is known
        self._wrong_chain = None            # a scan's chain that reached one of them
        self._mounted = False
        self._mount_laser = None
        """Odom mode with a mount: the frame of the first scan, the laser the mount is of."""
        self._newest = {}
        """Child frame -> (stamp, translation, rotation) of its newest dynamic edge sample."""
        self._odom_refused = None
        """(frame, count) of the odometry refused for its frame, while none was taken."""
        self._odom_taken = False
        self._scan_edge = None
        """(frame, target) of the newest scan's own pose lookup (``rate_notes``)."""
        self._scan_stamps = deque(maxlen=ODOM_SLOW[2] + 1)
        self._rate_scans = 0
        self._rate_frame = None
        self._rate_said = False
        self._tree = {}
        """Scan mode: child frame -> (parent, static, (x, y, yaw) of the edge or None when not
        planar, whether it turns the child upside down) from the transforms seen
        (``scan_root``, ``upside_down``)."""
        self._scan_laser = None
        """Scan mode: the frame of the first scan, the one laser it follows."""
        self._flips = {}
        """Scan mode: laser frame -> whether its scans were placed upside down."""
        self._flip_note = None
        """Scan mode: the ``laser_flip`` warning, once: (cause, text), then ()."""

    def add(self, record) -> Optional[tuple]:
        """
        Take a Transform or an Odometry record (others are ignored).

        Returns (cause, text) of a warning to log (the clock jumped back), else None. Raises
        RecordSkipped for a record that cannot be used (bad numbers, odometry in another frame).
        """
        odom_mode = self.options.pose_source == 'odom'
        note = None
        if self.options.pose_source == 'scan':
            # scan mode: poses come from the scans alone; transforms only say where the laser
            # hangs and who owns the root of its tree (``scan_root``)
            if isinstance(record, Transform):
                self._note_edge(record)
            return None
        if isinstance(record, Transform):
            if odom_mode and not record.static:
                return None         # odom mode: the odometry topic is the only moving edge
            if self.localizer and record.parent == self.fixed_frame:
                if record.child == self.odom_frame:
                    return None     # our own map -> odom read back: never a pose source
                self._under_fixed.add(record.child)
                text = (f'ignored transform {record.parent} -> {record.child}: with scan '
                        f'matching this session owns the map frame {self.fixed_frame!r} '
                        '(another localizer, or fixed_frame set to the odometry frame?)')
                if self.base_frame is None:
                    # Before the robot's chain is known: said once it is, if the frame is on
                    # it (another robot's map -> its odom, on a shared map frame, is not).
                    if len(self._held) < MAX_SCAN_FRAMES:
                        self._held.setdefault(record.child, text)
                    return None
                return ('tf_frames', text) if self._on_our_chain(record.child) else None
            if not record.static:
                if not self._in_order(record.parent, record.child, record.stamp,
                                      record.translation, record.rotation):
                    return None
                note = self._time_jump(record.stamp, record.child)
            self._set(record.parent, record.child, record.stamp, record.translation,
                      record.rotation, record.static)
        elif isinstance(record, Odometry) and odom_mode:
            if self.localizer:
                if self.odom_frame is None:
                    self.odom_frame = record.frame_id
                elif record.frame_id != self.odom_frame:
                    self._refuse_odometry(record.frame_id)
                    which = ('odom_frame' if self.options.odom_frame
                             else 'the first odometry')
                    raise RecordSkipped('odom_frame', f'odometry in frame {record.frame_id!r}, '
                                        f'expected {self.odom_frame!r} as {which}')
            elif self.fixed_frame is None:
                self.fixed_frame = record.frame_id
            elif record.frame_id != self.fixed_frame:
                self._refuse_odometry(record.frame_id)
                raise RecordSkipped('odom_frame', f'odometry in frame {record.frame_id!r}, '
                                    f'expected {self.fixed_frame!r} (with pose source odom the '
                                    'map is in the odometry frame)')
            self._odom_taken = True
            self.base_frame = record.child_frame_id
            if not self._in_order(record.frame_id, record.child_frame_id, record.stamp,
                                  record.translation, record.rotation):
                return None
            note = self._time_jump(record.stamp, record.child_frame_id)
            self._set(record.frame_id, record.child_frame_id, record.stamp, record.translation,
                      record.rotation, False)
            m = self.options.mount
            if m is not None and not self._mounted:
                self._set(record.child_frame_id, MOUNT_FRAME, 0.0, (m[0], m[1], 0.0),
                          mount_quaternion(m[2], self.options.mount_upside_down), True)
                self._mounted = True
        return note

    def _in_order(self, parent, child, stamp, translation, rotation) -> bool:
        """
        Return whether to store a dynamic edge sample: False for a copy of the edge's newest.

        Raises RecordSkipped for another pose at or before the newest stamp (a stuck or
        stepped clock: the pose of another time), as tf2 ignores TF_REPEATED_DATA. A step back
        beyond the cache, or of the edge's own stamps by more than ``TIME_JUMP_BACK``, is a time
        jump (``_time_jump`` clears the buffer), not this.
        """
        last = self._newest.get(child)
        if last is None or stamp > last[0] or self._jumped(child, stamp):
            return True
        if stamp == last[0] and np.array_equal(translation, last[1]) \
                and np.array_equal(rotation, last[2]):
            return False
        raise RecordSkipped('stamp_order', f'ignored {parent} -> {child} stamped {stamp:.3f}: '
                            + ('the same stamp as the previous one with another pose'
                               if stamp == last[0] else
                               f'{last[0] - stamp:.3f} s before the previous one')
                            + ' (pose data must come in stamp order)')

    def _note_edge(self, record: Transform) -> None:
        """Scan mode: keep a transform's edge for ``scan_root`` (not our own fixed-frame one)."""
        if record.parent == (self.fixed_frame or self.options.fixed_frame or 'map'):
            return                  # our own broadcast read back (or another's: see scan_root)
        if record.child not in self._tree and len(self._tree) >= SCAN_TREE_FRAMES:
            return
        try:
            flat = planar_edge(record.translation, record.rotation)
            xyz, flip = flat.xyz, flat.flip
        except (TransformLookupError, ValueError):
            xyz, flip = None, False
        self._tree[record.child] = (record.parent, bool(record.static), xyz, flip)

    def _static_chain(self, frame: str) -> tuple:
        """
        Scan mode: the mounts from ``frame`` up its static transforms: (edges, root, why).

        ``edges``: (x, y, yaw, flip) of each, child first; ``root``: the first frame without a
        static parent; ``why``: '' or why the chain cannot be used (a transform on /tf gives
        a frame a parent, a mount is tilted or invalid, a loop).
        """
        edges, seen = [], {frame}
        while frame in self._tree:
            parent, static, mount, flip = self._tree[frame]
            if not static:
                return edges, frame, (f'{frame} already has a parent on /tf ({parent} -> '
                                      f'{frame}); with odometry use pose_source tf or odom and '
                                      'scan_matching')
            if mount is None:
                return edges, frame, (f'the mount {parent} -> {frame} is not planar (tilted '
                                      'or invalid)')
            if parent in seen:
                return edges, frame, f'the static transforms above {frame} form a loop'
            edges.append((*mount, flip))
            frame = parent
            seen.add(frame)
        return edges, frame, ''

    def upside_down(self, frame: str) -> bool:
        """
        Scan mode: whether the laser ``frame`` hangs upside down under the root of its tree.

        By every transform above it, static or not (a mount a ROS 1 static_transform_publisher
        or a converted bag sends on /tf: until an audit only /tf_static's counted, and such a
        laser was mirrored); an odometry's turns nothing over.
        """
        flips, seen = 0, {frame}
        while frame in self._tree:
            parent, _, _, flip = self._tree[frame]
            flips += flip
            if parent in seen:
                break
            frame = parent
            seen.add(frame)
        return flips % 2 == 1

    def scan_root(self, frame: str, laser_pose) -> tuple:
        """
        Scan mode: the root of ``frame``'s tree and its pose in the fixed frame: (root, pose, '').

        From the laser pose the scans placed, up the static transforms (the mounts on
        /tf_static) to the frame without a static parent: what the node broadcasts under the
        fixed frame (as hector_mapping broadcasts map -> base_link), so RViz and tf2 place the
        laser and the robot. (None, None, why) when a transform on /tf already gives that root
        a parent (odometry: tf2 would then see two parents; use ``pose_source`` tf or odom with
        ``scan_matching`` there), or a mount is not planar.
        """
        edges, root, why = self._static_chain(frame)
        if why:
            return None, None, why
        if self._flips.get(frame, False) != (sum(e[3] for e in edges) % 2 == 1):
            return None, None, (f'the mounts above {frame} turn it upside down and its scans '
                                'were placed upright, or the other way round (a mount that '
                                'came after the first scans)')
        if not any(e[3] for e in edges):        # upright mounts: composed as before, exactly
            pose = np.asarray(laser_pose, dtype=np.float64)
            for edge in edges:
                pose = _compose(pose, _inverse(np.asarray(edge[:3])))
            return root, pose, ''
        # Planar poses as 2D affine maps (``_affine``). The root's map is the laser's times the
        # inverse of the chain's (root -> laser).
        chain = np.eye(3)
        for edge in edges:                      # child first: root -> laser = e_n ... e_1
            chain = _affine(*edge) @ chain
        laser = _affine(*np.asarray(laser_pose, dtype=np.float64), self._flips.get(frame, False))
        at = laser @ np.linalg.inv(chain)
        return root, np.array([at[0, 2], at[1, 2], math.atan2(at[1, 0], at[0, 0])]), ''

    def _set(self, parent, child, stamp, translation, rotation, static) -> None:
        self._last_lookup = None
        try:
            self.buffer.set_transform(parent, child, stamp, translation, rotation, static)
        except ValueError as exc:
            raise RecordSkipped('bad_transform', f'ignored transform {parent} -> {child}: '
                                f'{exc}') from None
        self._parents[child] = parent
        if static:
            self._static.add(child)
        else:
            self._static.discard(child)
            self.latest = max(self.latest, stamp)
            self._newest[child] = (stamp, translation, rotation)
        if len(self._parents) > 2 * self.buffer.max_frames:
            # the buffer dropped expired one-off frames (a tracker's): so do these notes
            known = self.buffer.frames()
            for notes in (self._parents, self._newest):
                for name in [c for c in notes if c not in known]:
                    del notes[name]

    def _jumped(self, child: str, stamp: float) -> bool:
        """
        Return whether a dynamic sample of ``child`` at ``stamp`` says the clock jumped back.

        By the edge's own stamps (as tf2 keeps a cache per frame), and, once a scan was posed,
        only for an edge on its chain. Another robot's transforms on a shared /tf stamped a
        minute behind (a clock set wrong, a robot on sim time) were taken for a jump of the
        clock against the newest stamp of all: each dropped every stored transform, and a
        localizer restarted at its start (a multi-robot audit: 5 of 60 scans used).
        """
        last = self._newest.get(child)
        if last is None or stamp >= last[0] - TIME_JUMP_BACK:
            return False
        return self._scan_edge is None or child in self._dynamic_edges(*self._scan_edge)

    def _time_jump(self, stamp: float, child: str) -> Optional[tuple]:
        if not self._jumped(child, stamp):
            return None
        # The clock jumped back (a bag restarted, a simulation reset): what is stored is from
        # another time line; as tf2_ros does, forget it.
        gap = self._newest[child][0] - stamp
        self.buffer.clear(keep_static=True)
        self._last_lookup = None
        self.latest = -math.inf
        self._newest.clear()
        return ('time_jump', f'pose data stamped {stamp:.3f}, {gap:.1f} s before the newest: '
                'the clock jumped back, dropping the stored dynamic transforms')

    def pose(self, scan: Scan, stamp: Optional[float] = None,
             tolerance: Optional[float] = None) -> PlanarPose:
        """
        Return the laser pose of ``scan``; TransformLookupError (with ``cause``) if none.

        ``stamp`` (s): at that time instead of the scan's stamp (a beam's time); ``tolerance``
        (s): instead of the options'. Scan mode: the origin (the session predicts the pose from
        the matched motion).
        """
        if self.options.pose_source == 'scan':
            self.fixed_frame = self.fixed_frame or 'map'
            frame = scan.frame_id
            # Each scan is predicted from the last ones' motion: another laser's scans
            # (another frame on the topic), mounted elsewhere, would be matched as a jump.
            self._scan_laser = _one_laser(self._scan_laser, frame, lambda first: (
                f'scan mode follows one laser, {first!r} (the frame of the first scan; '
                "~/reset follows the next scan's): map several with pose_source 'tf' or "
                "'odom' and their mounts on /tf_static"))
            flip = self.upside_down(frame) if scan.pose is None else False
            first = self._flips.setdefault(frame, flip)
            if flip != first and self._flip_note is None:
                # The mount came after the first scans: they are placed as they were (a map
                # half mirrored matches nothing); said once.
                now, then = ('upside down', 'upright') if flip else ('upright', 'upside down')
                self._flip_note = ('laser_flip', (
                    f'the mounts above {frame!r} now say it is {now}, but its first scans were '
                    f'placed {then} '
                    '(no mount known yet): its scans stay placed so, and the map is '
                    'mirrored if the mount is right: call ~/reset (or replay again)'))
            return PlanarPose(0.0, 0.0, 0.0, first)
        if scan.pose is not None:
            x, y, yaw = (float(v) for v in scan.pose)
            return PlanarPose(x, y, yaw, False)
        frame = scan.frame_id
        if not frame:
            raise TransformLookupError('unknown_frame', 'the scan has an empty frame_id')
        if self.options.pose_source == 'odom':
            target = self.odom_frame if self.localizer else self.fixed_frame
            if target is None or not self._parents or not self._odom_taken or (
                    self.options.mount is not None and not self._mounted):
                raise TransformLookupError('no_tf', self._no_odometry(target))
            if self.options.mount is not None:
                # One mount for one laser: a second laser's scans (another frame on the
                # topic) placed with it would draw its room turned and shifted.
                self._mount_laser = _one_laser(self._mount_laser, frame, lambda first: (
                    f'the laser mount (laser_x, laser_y, laser_yaw) is that of {first!r}, the '
                    "frame of the first scan: pose_source 'odom' places one laser; map "
                    "several with pose_source 'tf' and their mounts on /tf_static"))
                frame = MOUNT_FRAME
        elif self.localizer:
            target = self._odometry_target(frame)
        else:
            target = self.fixed_frame or self._default_fixed(frame)
            if self.options.scan_matching and self.fixed_frame is None and target != 'map':
                # A tree without a map frame (odom -> base_link only): the matched poses leave
                # its root as the odometry drifts, so the map is 'map' above it (REP 105), as
                # in odom mode and the node's; the root is then the odometry frame.
                self.localizer, self.fixed_frame = True, 'map'
                self.odom_frame = self.options.odom_frame or None
                target = self._odometry_target(frame)
        pose = self.buffer.lookup_planar(target, frame, scan.stamp if stamp is None else stamp,
                                         self.options.tolerance if tolerance is None
                                         else tolerance)
        if stamp is None:
            self._scan_edge = (frame, target)
            if self.options.odom_gap_factor:
                self._check_odom_gap(frame, target, scan.stamp)
        if self.localizer:
            self.odom_frame = target
        else:
            self.fixed_frame = self.odom_frame = target
        return pose

    def rate_notes(self, stamp: float, frame: str) -> list:
        """
        Return an ``odom_rate`` warning (once) when the odometry is much slower than the scans.

        Called with each posed scan's stamp and frame (after ``pose``); see ``ODOM_SLOW``. The
        scans: the first laser's (lasers interleave); a step back of more than
        ``TIME_JUMP_BACK`` starts them again (a clock that jumped back), a smaller one is left
        out. The odometry: the stamps of the odometry edge of the scan's own lookup
        (``_odometry_edge``), read every ``ODOM_SLOW[2]`` scans, at least 4 of them (the
        buffer keeps ``cache_seconds``), and only while it moves (a mount sent on /tf instead
        of /tf_static is the lowest dynamic edge, but interpolating it is exact: the next
        dynamic edge up to the odometry frame is judged then; with the pose looked up in a
        fixed frame above the odometry's, only the lowest).
        """
        scans = self._scan_stamps
        if self._rate_frame is None:
            self._rate_frame = frame
        if self._rate_said or self._scan_edge is None or frame != self._rate_frame:
            return []
        if scans and stamp <= scans[-1]:
            if stamp >= scans[-1] - TIME_JUMP_BACK:
                return []
            scans.clear()
        scans.append(stamp)
        self._rate_scans += 1
        if len(scans) < scans.maxlen or self._rate_scans % ODOM_SLOW[2]:
            return []
        edges = self._dynamic_edges(*self._scan_edge)
        if self.options.pose_source == 'tf' and not self.localizer:
            # Up to a fixed frame above the odometry (map): a localizer's map -> odom is on
            # the way, and a still odometry edge below it is a parked robot, not a mount.
            edges = edges[:1]
        for child in edges:
            odom = self.buffer.stamps(child)[-scans.maxlen:]
            if len(odom) < 4:
                return []
            if not self.buffer.still(child, len(odom)):
                break
        else:
            return []
        period = float(np.median(np.diff(odom)))
        scan_period = float(np.median(np.diff(np.asarray(scans))))
        if not (period >= ODOM_SLOW[0] and period >= ODOM_SLOW[1] * scan_period):
            return []
        self._rate_said = True
        what = ('the odometry' if self.options.pose_source == 'odom' else
                f'the transform {self._parents[child]} -> {child}')
        return [('odom_rate', f'{what} comes every {1e3 * period:.0f} ms ({1 / period:.1f} '
                 f"Hz), {period / scan_period:.0f} x the scans' interval: each scan and its "
                 'beams are posed by interpolating across it, which spreads every change of '
                 'the turn rate over it and smears the map in turns. Publish it at 5 Hz or '
                 'more (diff_drive_controller: publish_rate)')]

    def forget_lasers(self) -> None:
        """Scan mode, after ~/reset: follow the laser of the next scan, its flip decided again."""
        self._flips.clear()
        self._flip_note = None
        self._scan_laser = None

    def flip_notes(self) -> list:
        """Scan mode: the ``laser_flip`` warning once, when a laser's mount turned it over."""
        if not self._flip_note:
            return []
        note, self._flip_note = self._flip_note, ()
        return [note]

    def held_notes(self) -> list:
        """
        Return the warnings held back until the robot's chain was known.

        Those of transforms from the fixed frame to a frame on it (``add``), or on a scan's
        chain that could only reach the fixed frame through one (fixed_frame set to the
        odometry frame); the others are dropped.
        """
        if not self._held or (self.base_frame is None and self._wrong_chain is None):
            return []
        held, self._held = self._held, {}
        return [('tf_frames', text) for child, text in held.items()
                if self._on_our_chain(child) or child in (self._wrong_chain or ())]

    def _on_our_chain(self, frame: str) -> bool:
        """
        Return whether ``frame`` lies on our robot's chain (localizer, its base frame known).

        A transform fixed frame -> it is then another localizer's over our robot, or
        fixed_frame is set wrong; another robot's odometry frame under a shared map frame is
        not on it.
        """
        try:
            return frame in self._chain(self.base_frame)
        except TransformLookupError:
            return False

    def _refuse_odometry(self, frame: str) -> None:
        """Count an odometry message refused for its frame while none has been taken."""
        if not self._odom_taken:
            seen, n = self._odom_refused or (frame, 0)
            self._odom_refused = (frame, n + 1) if seen == frame else (frame, 1)

    def _no_odometry(self, target: Optional[str]) -> str:
        """Say why odometry mode has no pose yet: none came, or what came was refused."""
        where = '' if target is None else f' in frame {target!r}'
        if self._odom_refused is not None and not self._odom_taken:
            frame, n = self._odom_refused
            return (f'no usable odometry yet: {n} message(s) in frame {frame!r}, none{where} '
                    '(see the odom_frame warning)')
        return f'no odometry received yet{where}'

    def _odometry_edge(self, frame: str, target: Optional[str]) -> Optional[str]:
        """
        Return the child frame of the odometry edge above ``frame``, None when it has none.

        The odometry edge is the lowest moving transform between the laser and ``target``
        (None or not on the chain: its root): odom -> base_link under REP 105 (in odom mode
        the odometry's own), with the static mount below it and a localizer's map -> odom
        above it, whose corrections come when they come and carry no motion of their own.
        """
        return next(iter(self._dynamic_edges(frame, target)), None)

    def _dynamic_edges(self, frame: str, target: Optional[str]) -> list:
        """
        Return the child frames of the dynamic edges from ``frame`` up to ``target``, lowest first.

        ``target`` None or not on the chain: up to its root; [] when the chain is not known.
        """
        try:
            chain = self._chain(frame)
        except TransformLookupError:
            return []
        top = chain.index(target) if target in chain else len(chain) - 1
        return [child for child in chain[:top] if child not in self._static]

    def newest(self, scan: Scan) -> float:
        """
        Return the newest stamp of the pose data a lookup at ``scan``'s stamp interpolates in.

        Odom mode: the odometry's. Tf mode: the odometry edge's (``_odometry_edge``); a
        localizer's map -> odom newer than it says nothing about the motion at the scan.
        """
        if self.options.pose_source != 'tf':
            return self.latest
        child = self._odometry_edge(scan.frame_id, self.odom_frame if self.localizer
                                    else self.fixed_frame)
        entry = self._newest.get(child)
        return self.latest if entry is None else entry[0]

    def _check_odom_gap(self, frame: str, target: str, stamp: float) -> None:
        """
        Raise TransformLookupError ``odom_gap`` if ``stamp`` lies in a gap of the odometry.

        The odometry: the stamps the buffer holds of ``frame``'s odometry edge to ``target``
        (``_odometry_edge``: the odometry messages in odom mode). A gap: two neighbours more
        than ``odom_gap_factor`` times the median of the newest ``ODOM_GAP_STEPS[1]`` intervals
        apart, and more than ``ODOM_GAP_MIN``.
        """
        child = self._odometry_edge(frame, target)
        if child is None:
            return
        stamps = self.buffer.stamps(child)
        factor = self.options.odom_gap_factor
        if not factor or len(stamps) <= ODOM_GAP_STEPS[0]:
            return
        i = bisect.bisect_left(stamps, stamp)
        if i == 0 or i >= len(stamps) or stamps[i] == stamp:
            return                  # at a message, or outside them (the tolerance rules)
        gap = stamps[i] - stamps[i - 1]
        if gap <= ODOM_GAP_MIN:
            return
        newest = itertools.islice(reversed(stamps), ODOM_GAP_STEPS[1] + 1)
        typical = float(np.median(-np.diff(np.fromiter(newest, dtype=np.float64))))
        if gap > factor * typical:
            what = ('odometry' if self.options.pose_source == 'odom' else
                    f'transform {self._parents[child]} -> {child}')
            raise TransformLookupError(
                'odom_gap', f'no {what} between {stamps[i - 1]:.3f} and {stamps[i]:.3f} s '
                f'({gap / typical:.1f} x its typical interval of {1e3 * typical:.0f} ms): a '
                'message was lost, and the motion in the gap is unknown')

    def base_pose(self, stamp: float) -> Optional[np.ndarray]:
        """Return (x, y, yaw) of ``base_frame`` in ``odom_frame`` at ``stamp``, or None."""
        if self.base_frame is None or self.odom_frame is None:
            return None
        try:
            return self._lookup(self.odom_frame, self.base_frame, stamp).xyz
        except TransformLookupError:
            return None

    def robot_pose(self, scan: Scan, laser: Optional[PlanarPose] = None) -> np.ndarray:
        """
        Return (x, y, yaw) of the robot carrying the laser of ``scan``, in ``pose``'s frame.

        The robot is the frame the laser is mounted on (its parent by a static transform: the
        odometry child frame with ``mount``), or the laser itself when it has no mount (or the
        scan carries its pose). Call after ``pose(scan)`` succeeded (``laser``: what it
        returned, not looked up again); its lookup failing, the laser pose is returned.
        """
        laser = self.pose(scan) if laser is None else laser
        frame = scan.frame_id
        if self.options.pose_source == 'odom' and self.options.mount is not None:
            frame = MOUNT_FRAME
        if scan.pose is not None or frame not in self._static or frame not in self._parents:
            return laser.xyz
        target = self.odom_frame if self.localizer else self.fixed_frame   # as ``pose``'s
        try:
            return self._lookup(target, self._parents[frame], scan.stamp).xyz
        except TransformLookupError:
            return laser.xyz

    def _lookup(self, target: str, source: str, stamp: float) -> PlanarPose:
        """Return ``buffer.lookup_planar`` of ``source`` in ``target`` (the last one kept)."""
        key = (target, source, stamp, self.options.tolerance)
        if self._last_lookup is not None and self._last_lookup[0] == key:
            return self._last_lookup[1]
        pose = self.buffer.lookup_planar(target, source, stamp, self.options.tolerance)
        self._last_lookup = (key, pose)
        return pose

    def _odometry_target(self, frame: str) -> str:
        """
        Return the odometry frame to look ``frame`` up in (localizer, tf mode); set base_frame.

        The top of ``frame``'s chain, or ``odom_frame`` (given, or found once) on it. Raises
        TransformLookupError when a given ``odom_frame`` is not on the chain, when that frame
        already has a parent on /tf, or when the chain reaches it through static transforms
        only (no odometry yet).
        """
        chain = self._chain(frame)
        if self.options.odom_frame and self.options.odom_frame not in chain:
            raise TransformLookupError(
                'no_tf', f'frame {frame!r} does not reach odom_frame '
                f'{self.options.odom_frame!r} (its tree goes up to {chain[-1]!r})')
        if self.odom_frame in chain:
            # The odometry frame, given or found (the root) once, stays it: a frame
            # another node later puts above it (a second robot's localizer) is not ours.
            chain = chain[:chain.index(self.odom_frame) + 1]
        target = chain[-1]
        if target in self._parents:
            raise TransformLookupError(
                'tf_frames', f'the odometry frame {target!r} has the parent '
                f'{self._parents[target]!r} on /tf: {self.fixed_frame} -> {target} would '
                f'give it a second one. Put {self.fixed_frame!r} under '
                f'{self._parents[target]!r} instead'
                + ('' if self.options.odom_frame else ", or set odom_frame (the robot's "
                   'own odometry frame)'))
        if target in self._under_fixed and self._static.issuperset(chain[:-1]):
            self._wrong_chain = chain       # its held warning is said (``held_notes``)
            raise TransformLookupError(
                'tf_frames', f'frame {frame!r} moves only through the ignored transform '
                f'{self.fixed_frame} -> {target}: with scan matching fixed_frame must be a '
                'map frame above the odometry frame')
        if self._static.issuperset(chain[:-1]):
            # The odometry transform (odom -> base_link) has not come yet: the root is the
            # robot itself. Taken as the odometry frame, it was localized as one, and when
            # the odometry came map -> base_link gave base_link a second parent (a node
            # whose odometry driver started 1 s after the laser: 4.6 m off all run).
            raise TransformLookupError(
                'no_tf', f'frame {frame!r} reaches {target!r} only through static '
                'transforms: scan matching localizes the odometry frame, and no odometry '
                f'transform ({target!r} in it) has come yet (odometry only as '
                'nav_msgs/Odometry, no odom -> base_link on /tf: pose_source odom; no '
                'odometry at all: pose_source scan)')
        self.base_frame = chain[-2]
        return target

    def static_mount(self, frame: str) -> Optional[tuple]:
        """
        Return (parent, PlanarPose) of ``frame`` under the frame its static transforms hang from.

        That is the laser's mount on the robot as /tf_static gives it (what odom mode uses
        without ``mount``); None when the frame has no static parent or the mount cannot be
        placed in the plane.
        """
        top, seen = frame, {frame}
        while top in self._static and top in self._parents:
            top = self._parents[top]
            if top in seen:
                return None         # static transforms in a loop (a hostile recording)
            seen.add(top)
        if top == frame:
            return None
        try:
            stamp = self.latest if math.isfinite(self.latest) else 0.0     # (static: any)
            return top, self.buffer.lookup_planar(top, frame, stamp, math.inf)
        except (TransformLookupError, ValueError):
            return None

    def _chain(self, frame: str) -> list:
        """Return [frame, its parent, ..., the root of its tree]; TransformLookupError if alone."""
        chain, seen = [frame], {frame}
        while chain[-1] in self._parents and self._parents[chain[-1]] not in seen:
            chain.append(self._parents[chain[-1]])
            seen.add(chain[-1])
        if len(chain) == 1:
            raise TransformLookupError(
                'unknown_frame' if self._parents else 'no_tf',
                f'frame {frame!r} has no transform to any other frame yet')
        return chain

    def _default_fixed(self, frame: str) -> str:
        chain = self._chain(frame)
        if 'map' in chain:
            return 'map'
        if self._static.issuperset(chain[:-1]):
            # Only the mount is known yet (a recording whose /tf starts after its first
            # scans): its root is the robot, not a map frame; mapped there, every scan would
            # sit at the origin. The moving transforms may still come: the scan waits.
            raise TransformLookupError(
                'no_tf', f'frame {frame!r} reaches {chain[-1]!r} only through static '
                'transforms: no moving transform places it in a map frame yet (a sensor '
                f'that does not move: give the fixed frame, e.g. {chain[-1]!r})')
        return chain[-1]


class Localization(NamedTuple):
    """
    Scan matching: where the newest mapped scan put the robot (``MappingSession.localization``).

    The node broadcasts ``correction`` as fixed frame -> ``odom_frame`` on /tf and ``pose`` with
    ``covariance`` as geometry_msgs/PoseWithCovarianceStamped.
    """

    stamp: float
    """The scan's stamp, seconds."""
    pose: np.ndarray
    """(3,) x, y, yaw of the base frame (the odometry child; the laser without one) in the
    fixed frame."""
    covariance: np.ndarray
    """(3, 3) over the pose's (x, y, yaw), m^2 and rad^2: the match's (``ScanMatch``), or the
    prediction's prior when the match was refused or there was no map yet."""
    correction: np.ndarray
    """(3,) fixed frame <- ``odom_frame`` (x, y, yaw): map -> odom."""
    matched: bool
    """The pose is the scan's match against the map (else the prediction)."""
    residual: float
    """Robust RMS distance (m) of the matched points to the map (NaN when not matched)."""
    odom_frame: Optional[str]
    """The frame the poses came in (odometry frame, root of the scan frame's tree); None when
    the scans carried their own poses."""
    base_frame: Optional[str]
    """The frame whose pose ``pose`` is (None: the laser's)."""
    scan_frame: Optional[str] = None
    """The laser frame of the scan."""


_PRIOR = match_scan(np.zeros((0, 2)), np.zeros(3), np.zeros((0, 2, 2)), 1.0).covariance
"""The prior covariance match_scan reports with a refused match (used before any map)."""
MAX_MAP_SIGMA = CORE_RANGES['smemsf.sigma'][1]
R_OVER_SIGMA = CORE_RANGES['smemsf.r_over_sigma'][1]
"""A saved map's noise scale (m) is taken up to smemsf.sigma's largest value, its r up to
r_over_sigma's largest times that; beyond, it is not a noise scale (1e300 overflowed the
match covariance)."""


def saved_noise_scale(stats) -> tuple:
    """
    Return a saved map's (sigma, r) from its stats, metres; None for either that is unusable.

    Unusable: missing, not a number, not finite, <= 0 or beyond ``MAX_MAP_SIGMA`` (r: beyond
    ``R_OVER_SIGMA`` times that, or without a usable sigma).
    """
    stats = stats or {}
    sigma, r = stats.get('sigma'), stats.get('r')
    if not (is_number(sigma) and 0 < sigma <= MAX_MAP_SIGMA):
        sigma = None
    if sigma is None or not (is_number(r) and 0 < r <= MAX_MAP_SIGMA * R_OVER_SIGMA):
        r = None
    return (None if sigma is None else float(sigma)), (None if r is None else float(r))


def require_noise_scale(value: MapValue, sigma_given: bool, advice: str) -> tuple:
    """
    Return a saved map's ``saved_noise_scale``; ValueError when it has segments and none.

    ``sigma_given``: the configuration fixes sigma itself (then none is needed). ``advice``
    ends the message: how to give one, in the words of the caller (node or command line).
    """
    sigma, r = saved_noise_scale(value.stats)
    if len(value.segments) and sigma is None and not sigma_given:
        raise ValueError(f'the map has no noise scale (stats.sigma, in (0, {MAX_MAP_SIGMA:g}] '
                         f'm; got {(value.stats or {}).get("sigma")!r}): scans cannot be '
                         f'matched against it; {advice}')
    return sigma, r


MAX_SCAN_FRAMES = 64
"""Laser frames whose newest scan stamp is kept for the stamp order check (junk frame names
cannot grow it)."""
SCAN_SKIPS = ('bad scan', 'no pose', 'not mapped')
"""The categories of ``MappingSession.skipped`` that count scans (the others: pose data,
undecodable messages; ``dropped`` is load shedding, counted apart)."""
STAMP_LEAP = 1.0
"""Seconds a scan's stamp may lie before its laser's newest scan, or beyond it by more than the
laser's last step, before it is held with the laser's next scans
(``MappingSession._add_scan``): ``LEAP_CONFIRM`` scans on the held scan's time line (a clock
that jumped, scans after a gap) take it; one back on the old line (closer to the newest than
to the last held scan) makes the held scans misstamped, skipped (``stamp_order``). One scan
stamped 100 s ahead had ended scan mode's mapping for good (a gap too long to search, then
every later scan a jump back), and copies stamped 5 s back were mapped in tf mode at the
robot's pose of 5 s before (node audit: 117 segments against 24). A laser's second scan more
than 1 s after its first is held too (no step is known yet): a recording thinned to scans
more than ``transform_cache`` / 3 apart (``replay --every``) loses it as too_old, while one
or two misstamped scans right after the first are skipped (taking the second at once, or on
one more scan, bent scan mode's map: two audits)."""
LEAP_CONFIRM = 3
"""Scans on a new time line (the held one and the next) that make it the laser's: two copies
stamped 5 s early in a row passed as a clock jump with 2 (helper audit). A burst of this many
misstamped scans still passes; a real jump costs the first scans of the new line this many
scans of delay (live, held no longer than ``STAMP_LEAP`` and this many + 1 of the laser's
steps)."""
JUMP_WINDOW = 50
"""Matched scans whose residuals make the running median of the jump warning."""
JUMP_RESIDUAL = 2.5
"""A residual above this times the running median is a jump (warned, counted). The residual is
a robust RMS inside the match gate, so it seldom exceeds 3x its typical value; on the drifted
Intel, CSAIL and fr079 logs (seed 0) it peaks at 1.87x, 2.14x and 2.38x."""
JUMP_SHIFT, JUMP_TURN = 0.3, 0.2
"""A match this far (m, rad) from its odometry prediction (map -> odom changing by as much at
the laser in one scan) is a jump."""
LAG_ROWS = 5000
"""Matched scans (stamp, the odometry's heading, the matched heading) kept at most to pair the
newest ones with those ``poses.LAG_SPAN`` before (the stamp-lag estimate, ``poses.lag_costs``).
A pair is scored once the rows reach the grid's second past its later scan and a second before
its earlier one; after each estimate the rows older than ``LAG_KEEP`` before the last scored
scan are dropped, so they hold a ``LAG_EVERY`` batch plus about 4 s of scans: 140 rows at
10 Hz, 500 at 100 Hz (a fixed 300 rows lost pairs above 66 Hz and every one from 100 Hz on: a
helper audit). The cap binds only beyond 1 kHz."""
LAG_KEEP = 3.0
"""Seconds of rows kept before the newest scored scan: the span of a pair plus the grid's reach
before its earlier scan (``poses.LAG_SPAN`` + ``poses.LAG_GRID``'s end), and a second more."""
LAG_EVERY = 100
"""Matched scans between two stamp-lag estimates (each adds its pairs' costs, one grid pass)."""
LAG_DECAY = 0.95
"""Weight the costs summed so far keep at each estimate: the evidence of turns a few minutes
old fades (half of it after 14 estimates, 2.3 minutes at 10 Hz), so a lag that changes (a
driver restarted on another clock) shows."""
LAG_PAIRS = 30.0
"""Weighted pairs (of scans whose odometry turn depends on the lag) an estimate needs."""
LAG_WARN = 0.03
"""Seconds of stamp lag that are warned about (``scan_clock``), when the matched turns agree
with the odometry shifted by it at least ``LAG_SURE`` times better than unshifted; warned again
when the estimate moves as much from the value warned about (a lag that changed: a driver
restarted on another clock; the faded older evidence delays that, ``LAG_DECAY``). A 10 Hz
simulated office drive at 0.5 m/s, turning 1 rad/s, maps as with right stamps at 0.05 s and
not at 0.1 s (walls F1 0.85, benchmarks/scan_clock.py)."""
LAG_SURE = 1.5
"""The estimate's RMS disagreement must be at most 1 / this of the unshifted one's. On the
simulated drives of benchmarks/scan_clock.py the ratio is 1.00-1.20 with right stamps and
2.3-3.3 with stamps 0.1 s late."""


class WarningThrottle:
    """Log each cause at most once per ``period`` seconds; count every occurrence."""

    def __init__(self, log: Callable[[str], None], period: float = 10.0,
                 clock: Callable[[], float] = time.monotonic):
        self.log = log
        self.period = float(period)
        self.clock = clock
        self.counts = Counter()
        self.seen = {}
        """Cause -> the clock at its newest occurrence (logged or not)."""
        self._last = {}
        self._since = {}
        self._lock = threading.Lock()

    def recent(self, cause: str, within: float) -> bool:
        """Whether ``cause`` occurred within the last ``within`` seconds."""
        seen = self.seen.get(cause)
        return seen is not None and self.clock() - seen <= within

    def warn(self, cause: str, text: str) -> bool:
        """Count one occurrence of ``cause``; log ``text`` unless logged within the period."""
        now = self.clock()
        with self._lock:
            self.counts[cause] += 1
            self.seen[cause] = now
            last = self._last.get(cause)
            if last is not None and now - last < self.period:
                self._since[cause] = self._since.get(cause, 0) + 1
                return False
            more = self._since.pop(cause, 0)
            self._last[cause] = now
        suffix = f' ({more} more since the last warning of this cause)' if more else ''
        self.log(f'{text} [{cause}]{suffix}')
        return True


def _percentiles(values) -> dict:
    v = 1e3 * np.asarray(values, dtype=float)
    return {'p50': float(np.percentile(v, 50)), 'p95': float(np.percentile(v, 95)),
            'p99': float(np.percentile(v, 99)), 'max': float(v.max())}


def _found_places(points: np.ndarray, segments: np.ndarray, center: np.ndarray, radius: float,
                  turn: float, sigma: float) -> tuple:
    """
    Search ``points`` on ``segments`` within ``radius`` m and ``turn`` rad of ``center``.

    Returns (best, rivals): ``search_after_gap``'s candidates refined by ``match_scan`` (scan
    mode's degeneracy guard), the one putting most of the points on the segments (None when
    none matched), and the others more than 0.5 m or 0.3 rad from it within ``GAP_RIVAL`` of
    its share, best first. After a gap, near a pose estimate, and when not localized.
    """
    far = radius + 0.5 + float(np.hypot(points[:, 0], points[:, 1]).max())
    near = segments[in_box(segments, center[:2] - far, center[:2] + far)]
    found = [m for m in (match_scan(points, c, near, sigma, degenerate=MATCH_DEGENERATE['scan'])
                         for c in search_after_gap(points, near, center, radius, turn))
             if m.ok]
    if not found:
        return None, []
    found.sort(key=lambda m: -m.share)
    best = found[0]
    return best, [m for m in found[1:] if m.share >= best.share - GAP_RIVAL and (
        math.hypot(*(m.pose[:2] - best.pose[:2])) > 0.5
        or abs(wrap_angle(m.pose[2] - best.pose[2])) > 0.3)]


def _not_seen_through(segs: np.ndarray, support: np.ndarray, recent: np.ndarray,
                      origin: np.ndarray, points: np.ndarray, tol: float) -> tuple:
    """
    Leave out the young segments and recent chords the scan sees through.

    Returns (segs, support, recent, kept): ``kept`` (R,) bool, which of ``recent`` are left.

    Young: ``support`` below ``ESTABLISHED_SUPPORT``. Seen through: by the beams ``origin`` ->
    ``points`` (the scan at its predicted pose), ``core.cleanup.seen_through`` with noise
    margin ``tol`` (``MATCH_SEEN_THROUGH``). What is left may be nothing (the scan sees
    through all of the map near it): the match then keeps the prediction.
    """
    young = np.flatnonzero(support < ESTABLISHED_SUPPORT)
    pieces = np.concatenate([segs[young], recent])
    every = np.ones(len(recent), dtype=bool)
    if not len(pieces):
        return segs, support, recent, every
    gone = seen_through(pieces, origin, points, tol)
    if not gone.any():
        return segs, support, recent, every
    keep = np.ones(len(segs), dtype=bool)
    keep[young[gone[:len(young)]]] = False
    kept = ~gone[len(young):]
    return segs[keep], support[keep], recent[kept], kept


RECORD_TYPES = (Scan, Transform, Odometry, PoseEstimate, Skipped)
"""What ``MappingSession.add`` takes (``formats.records``)."""


def _check_record(record) -> None:
    """
    Raise TypeError / ValueError (one line) when ``record`` cannot be one of ``RECORD_TYPES``.

    Only its kind and the shapes of a scan's stamp and pose: values (NaN, a range beyond
    range_max, a stamp out of order) are the data's, skipped and counted in their turn. Before,
    ``add(None)`` was dropped without a word, and a Scan whose pose was (x, y) stopped every
    later ``step`` on the same unpacking error (an API audit).
    """
    if not isinstance(record, RECORD_TYPES):
        raise TypeError(f'MappingSession.add takes Scan, Transform, Odometry, PoseEstimate or '
                        f'Skipped records (polyline_mapper.formats.records), got '
                        f'{type(record).__name__}')
    if not isinstance(record, Scan):
        return
    for name in ('stamp', 'angle_min', 'angle_increment', 'range_min', 'range_max',
                 'time_increment', 'scan_time') + (('angle_max',) if record.angle_max is not None
                                                   else ()):
        value = getattr(record, name)
        if not is_real(value):
            raise TypeError(f'Scan.{name} must be a number, got {value!r}')
    try:
        np.asarray(record.ranges, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f'Scan.ranges must be numbers (metres), got {record.ranges!r:.80}') \
            from None
    if not isinstance(record.frame_id, str):
        raise TypeError(f'Scan.frame_id must be a str, got {record.frame_id!r}')
    if record.pose is not None:
        try:
            pose = np.asarray(record.pose, dtype=np.float64)
        except (TypeError, ValueError):
            pose = None
        if pose is None or pose.shape != (3,):
            raise ValueError(f'Scan.pose must be None or (x, y, yaw), got {record.pose!r}')


class MappingSession:
    """
    Records in, one map out: pose resolution, queue and give-up, grouping, timing, shedding.

    Thread-safe between producers (``add``; the node's subscription callbacks), one worker
    (``step``, ``flush``) and readers (``map``, ``stats``, ``reset``).

    ``clock``: None for data time (offline), or a function returning seconds (live: wall
    time). ``warn(cause, text)`` is called for every skipped record and other problems (the
    node passes a WarningThrottle); ``info(text)`` for notes.

    >>> from polyline_mapper.formats.records import Scan
    >>> session = MappingSession()
    >>> ranges = np.full(181, 2.0, dtype=np.float32)
    >>> scan = Scan(1.0, 'laser', -1.5708, 0.0174533, 0.1, 30.0, ranges, pose=(0.0, 0.0, 0.0))
    >>> session.add(scan)
    >>> session.step()                      # one group processed
    1
    >>> session.used, session.updates       # the first updates estimate the noise scale
    (1, 0)
    """

    def __init__(self, config: IncrementalConfig = None, options: SessionOptions = None,
                 clock: Optional[Callable[[], float]] = None,
                 warn: Optional[Callable[[str, str], object]] = None,
                 info: Optional[Callable[[str], object]] = None):
        self.options = config_of(options, SessionOptions, 'options')
        self._config = config_of(config, IncrementalConfig)
        """The mapper's configuration as given (``free_space_window`` -1: by the pose source)."""
        self.mapper = IncrementalMapper(self._config.resolved(self.options.scan_matching))
        self.grid = (None if self.options.grid_resolution is None
                     else FreeSpaceGrid(self.options.grid_resolution))
        """The free space traced by the mapped scans' beams (None without a grid)."""
        self.grid_seconds = deque(maxlen=100000)
        """Seconds each update spent tracing beams into the grid (not in ``update_ms``)."""
        self.poses = PoseSource(self.options)
        self.clock = clock
        self._warn = warn
        self._info = info
        self._lock = threading.Lock()           # queue, counters, pose source
        self._map_lock = threading.Lock()       # the mapper
        self._cv = threading.Condition(self._lock)
        self._waiting = deque()                 # (scan, arrival): checked, waiting for a pose
        self._ready = deque()                   # (scan, points, origin, seconds, arrival)
        self._generation = 0
        self._points = []
        self._origins = []                      # (scans' laser positions (S, 2), counts (S,))
        self.received = 0
        self.used = 0
        self._used_at_reset = 0                 # ``used`` when ``reset`` last cleared the map
        self.pose_kept = False
        """Whether the last ``reset`` kept the robot where it was matched (a saved map)."""
        self.updates = 0
        self.skipped = Counter()
        self.left_out = 0
        """Scans received and left out by ``every`` (not checked, not counted elsewhere)."""
        self.cleared = 0
        """Scans received and still queued when ``reset`` cleared the map."""
        self.examples = {}
        self.stamp = None
        """Stamp (s) of the newest scan in the map."""
        self._scan_stamps = {}
        """Frame id -> stamp (s) of its newest scan taken (at most MAX_SCAN_FRAMES frames)."""
        self._scan_steps = {}
        """Frame id -> the last step (s) forward between two of its scans taken."""
        self._leaps = {}
        """Frame id -> its scans held for a leap in their stamps (``STAMP_LEAP``): (scan,
        arrival on ``_now``), until the next scans decide."""
        self.update_seconds = deque(maxlen=100000)
        """Per update: the map update plus its scans' conversion (and matching), seconds."""
        self.convert_seconds = deque(maxlen=100000)
        """Per update: its scans' conversion (and matching) alone, seconds."""
        self.latency_seconds = deque(maxlen=100000)
        self._last_add = None
        self._correction = np.zeros(3)
        """Scan matching: fixed frame <- frame of the given poses (map -> odom), (x, y, yaw)."""
        self._recent = RecentChords(RECENT_SCANS, self.options.chord_knots)
        """Scan matching: chords of the last matched scans (fixed frame), the map's newest edge."""
        self._recent_pose = None
        """Scan matching: the pose of the newest keyframe in ``_recent``."""
        self._anchor = None
        """Scan matching: the robot base's given pose (TF / odometry) at the last matched scan:
        the start of the motion whose odometry error the next prediction carries."""
        self._anchor_at = None
        """Scan matching: (stamp s, laser pose in the fixed frame) of that scan."""
        self._anchor_step = None
        """Scan matching: (base motion (x, y, yaw) in the base frame, seconds) between the two
        last matched scans: the pace an odometry jump is judged against and predicted with.
        After a jump re-anchored on a pace, that pace's trial motion (``_odometry_jumped``)."""
        self._odom_jump = None
        """Scan matching: an odometry jump judged at this scan, to warn of: (its metres and
        radians off the pace, seconds since the last matched scan, 'anchored' on the pace,
        'followed' or 'kept': the odometry, 'searched': after a gap)."""
        self._reset_window = self._reset_at = None
        """Scan matching: (m, rad) around ``_reset_at`` (the laser pose the last matched scan's
        pace leads to) to search the scan in, when the odometry came back near its origin
        after a gap (``_reset_after_gap``)."""
        self.held = 0
        """Scan matching: matched scans with a direction held at the prediction (``held``)."""
        self._found = False
        """Scan matching: the last match ends a lost run (its jump was warned at the run's
        first scan)."""
        self._shares = deque(maxlen=RELOCALIZE_DROP[1])
        """Scan matching: the shares on the map of the last matched scans (``RELOCALIZE_DROP``)."""
        self._proposals = deque(maxlen=CONFIRM_JUMP)
        """Scan matching: the corrections (map -> odom) the last scans were refused for, in a
        row (``CONFIRM_JUMP``)."""
        self._trajectory = (deque() if self.options.keep_points
                            else deque(maxlen=TRAJECTORY_ROWS))
        self._first_base = None
        """The robot base's pose at the first scan mapped (x, y, yaw): scan mode searches there
        when its scans' clock jumps back (a recording played again from its start)."""
        self.matched_scans = None
        """Scan matching, offline: None, or a list the session appends (stamp, laser pose,
        laser-frame points, correction map -> odom) to for every matched scan (loop closure,
        ``replay``). Grows with the scans: set it only for a recording of known length."""
        self._motion = deque(maxlen=2)
        """(stamp, (x, y, yaw)) of the last two posed scans: the matched motion."""
        self._deskew: Optional[_Deskew] = None   # this scan's beams from the matched motion
        self._intervals = deque(maxlen=10)
        """Scan mode: seconds between the last posed scans (``GAP_FACTOR``)."""
        self._self_hits = {}
        """Laser frame -> its ``SelfHits`` (at most ``SELF_HIT_FRAMES``, the newest kept)."""
        self._gap = None
        """Scan mode: the ``GapTrack`` of the scans after a gap until one is found on the map."""
        self._last_scan = None
        self._quiet = None
        """Scan mode: the last scan's stamp, and the seconds from it to this scan's."""
        self._loaded = None
        """(MapValue, planner map or None, initial base pose or None) of ``load_map``."""
        self._place = None
        """The initial base pose (x, y, yaw) the next posed scan is placed at, or None."""
        self._spread = None
        """(m, rad) around ``_place`` to search (a pose estimate, ``set_pose``), or None."""
        self._rearm = None
        """``_spread`` of a pose estimate whose first scan saw nothing (``_blind``): the next
        scan is searched for there, carried by the odometry; or None."""
        self._start_check = []
        """On a loaded map: the pass-through shares of the first scans placed (``START_CHECK``)."""
        self.wrong_start = None
        """On a loaded map: the median share of the first scans' beams that pass through its
        walls when beyond ``START_CHECK`` (matched onto a wrong place), until the next reset or
        pose estimate; else None."""
        self.matches = Counter()
        """
        Scan matching outcomes: 'matched', 'relocalized' (``RELOCALIZE``), 'no map yet', and
        each refusal reason.
        """
        self.localization = None
        """Scan matching: the newest mapped scan's ``Localization`` (None before one)."""
        self.jumps = Counter()
        """Scan matching: 'residual', 'correction' and 'odometry' jumps warned about
        (``_localize``)."""
        self._residuals = deque(maxlen=JUMP_WINDOW)
        self._reckoned = None
        """Scan matching: the odometry's error since the last matched scan (``_reckon``)."""
        self._searched = None
        """Scan matching: the stamp of the last ``_search_reckoned`` (``RECKONED_SEARCH``)."""
        self._unmatched = None
        """On a saved map: [first stamp, scans, warned] of the scans not matched since the last
        matched one (``UNMATCHED_STREAK``); None after a match."""
        self._turns = deque(maxlen=LAG_ROWS)
        """(stamp, the laser's heading from the pose data, matched heading) of the matched
        scans of ``_lag_frame`` (TF or odometry with scan matching): ``lag_costs``' rows."""
        self._lag_frame = None              # the first matched laser (lasers lag apart)
        self._lag_costs = np.zeros(len(LAG_GRID))
        self._lag_pairs = 0.0
        self._lag_new = 0
        self._lag_since = -math.inf         # pairs up to this later stamp are counted
        self._lag_warned = None
        self.stamp_lag = None
        """The newest ``poses.StampLag`` estimate (every ``LAG_EVERY`` matched scans once
        ``LAG_PAIRS`` pairs count), or None."""
        self._last_match = None
        self._news = False
        self._estimating_noted = False

    def load_map(self, value: MapValue, initial_pose=None, grid: GridMap = None) -> None:
        """
        Start from a saved map (``formats.mapjson.read_map(...).value``): localization on it.

        The map's segments, support and noise scale (``stats['sigma']``, ``stats['r']``) become
        the mapper's G(0), its frame the frame of the map value. Scan matching is turned on
        (``options.scan_matching``): the given poses (odometry, TF) are in their own frame, and
        only matching registers the scans to the saved map; the mapper's ``free_space_window``
        left at -1 then resolves as with scan matching (0), as in a session started with it.
        A map in another frame than a given ``options.fixed_frame`` is taken in that frame
        (warning ``map_frame``). ``initial_pose`` (x, y, yaw; m, rad): where the robot (the
        frame the laser is mounted on, see ``PoseSource.robot_pose``) is in the map at the
        first scan; None: where the given poses say (the given frame is the map's). With
        ``options.mapping`` False the map is never changed: ``map_value`` returns the loaded
        segments, support, polylines and closed flags as they are, and ``occupancy`` the
        loaded planner map (``grid``) when there is one. With mapping True the scans are
        mapped into it. ``reset`` goes back to it.

        Raises ValueError (one line) when the map or the pose cannot be used (a map without a
        segment with mapping False: there is nothing to localize on, and nothing would be
        mapped).
        """
        if not self.options.mapping and not len(value.segments):
            raise ValueError('the saved map holds no segment: nothing to localize on (with '
                             'mapping false it would stay empty)')
        pose = None
        if initial_pose is not None:
            pose = np.asarray(initial_pose, dtype=np.float64)
            if pose.shape != (3,) or not np.isfinite(pose).all():
                raise ValueError(f'initial pose must be 3 finite numbers (x, y, yaw), got '
                                 f'{list(np.ravel(initial_pose))}')
        sigma, r = require_noise_scale(value, self.mapper.config.smemsf.sigma is not None,
                                       'give one (the parameter smemsf.sigma; replay --set '
                                       'sigma=M)')
        given = self.options.fixed_frame
        if given and value.frame_id != given:
            # One frame for the map, the poses, map -> odom and pose estimates (a localization
            # audit: a map saved in 'odom' was published in 'odom' while the pose and /tf
            # went out in 'map', 1.6 m apart in RViz, and initialpose was taken in 'odom').
            if self._warn is not None:
                self._warn('map_frame', f'the saved map is in frame {value.frame_id!r}; it is '
                           f'taken as the fixed frame {given!r} (the map, the pose, '
                           f'{given} -> odom and pose estimates are in {given!r})')
            value = replace(value, frame_id=given)
        with self._map_lock:
            mapper = self.mapper
            config = self._config.resolved(True)
            if config != mapper.config:     # the evidence's default follows scan matching
                mapper = IncrementalMapper(config)
            mapper.load(value.segments, value.support, sigma, r)
            self.mapper = mapper
        with self._cv:
            self.options.scan_matching = True
            self._loaded = (value, grid, pose)
            self._restart(pose)
        self._seed_grid()

    def _seed_grid(self) -> None:
        """Start the traced free space from a loaded map's planner map (mapping into it)."""
        if self.grid is None or self._loaded is None or self._loaded[1] is None:
            return
        with self._map_lock:
            self.grid.reset()
            self.grid.seed(self._loaded[1])

    def scan_root(self, loc: 'Localization') -> tuple:
        """
        Scan mode: what to broadcast under the fixed frame for ``loc``: (frame, pose, why).

        The root of the scan frame's tree (the frame its static mounts hang from; the laser
        frame without one) at the pose the scan put it, why '' (``PoseSource.scan_root``); or
        (None, None, why).
        """
        if loc.scan_frame is None:
            return None, None, 'no scan frame'
        with self._cv:
            return self.poses.scan_root(loc.scan_frame, loc.pose)

    def set_pose(self, pose, spread=(0.0, 0.0)) -> None:
        """
        Take a pose estimate: the robot base is at ``pose`` (x, y, yaw; m, rad) in the map now.

        What AMCL and slam_toolbox take on ``initialpose`` (RViz's "2D Pose Estimate"): to
        start localizing where the given poses are wrong, or to recover a lost session (a
        refused jump, a gap given up). Scan matching only: the next scan is predicted there.
        ``spread`` (m, rad): how far off the estimate may be (``POSE_ESTIMATE_SIGMAS``
        standard deviations of its covariance). When it is wider than the match's reach and
        there is a map, the scans are searched for within it (at most ``GAP_REACH`` and half
        a turn) as after a gap in the scans (``search_after_gap``: several keyframes, taken
        only when one place explains them) and not mapped until they are found. The recent
        scans' chords, the motion and a lost state are forgotten; the map is kept.

        Raises ValueError (one line; nothing changed) without scan matching or on a bad pose
        or spread.
        """
        if not self.options.scan_matching:
            raise ValueError('a pose estimate needs scan matching: without it scans are '
                             'mapped where TF or the odometry puts them')
        p = np.asarray(pose, dtype=np.float64)
        w = np.asarray(spread, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f'pose must be 3 finite numbers (x, y, yaw), got '
                             f'{list(np.ravel(pose))}')
        if w.shape != (2,) or not np.isfinite(w).all() or (w < 0).any():
            raise ValueError(f'spread must be 2 finite numbers >= 0 (m, rad), got '
                             f'{list(np.ravel(spread))}')
        with self._cv:
            self._take_estimate(p, w)

    def _take_estimate(self, pose: np.ndarray, spread: np.ndarray) -> Optional[tuple]:
        """``set_pose`` of a checked pose and spread (the lock held); the window searched."""
        pose = pose.copy()
        pose[2] = wrap_angle(pose[2])
        radius, turn = min(float(spread[0]), GAP_REACH), min(float(spread[1]), math.pi)
        tracked = self._localized_correction()
        self._restart(pose)
        self._tracked = tracked
        self._spread = (radius, turn) if (radius > MATCH_REACH[0]
                                          or turn > MATCH_REACH[1]) else None
        return self._spread

    def _estimate(self, record: PoseEstimate) -> list:
        """
        Take a pose estimate record in its turn among the scans (the lock held); notes.

        In the map's frame only (``map_frame``), with finite numbers and a covariance whose
        x, y and yaw variances are >= 0; else a skip ('pose estimate', warning cause
        ``initial_pose``). Its spread: ``POSE_ESTIMATE_SIGMAS`` standard deviations.
        """
        frame = self.map_frame
        pose = np.asarray(record.pose, dtype=np.float64).reshape(-1)
        cov = np.asarray(record.covariance, dtype=np.float64)
        var = (np.array([np.maximum(cov[0, 0], cov[1, 1]), cov[2, 2]]) if cov.shape == (3, 3)
               else np.full(2, np.nan))
        if record.frame_id != frame:
            why = f'in frame {record.frame_id!r}: it must be in {frame!r}, the map frame'
        elif pose.shape != (3,) or not np.isfinite(pose).all():
            why = (f'pose {pose.tolist()} is not 3 finite numbers (x, y, yaw; no yaw from a '
                   'quaternion that is not normalised)')
        elif not (np.isfinite(var).all() and (var >= 0).all()):
            why = 'its covariance has no finite variances >= 0 for x, y and yaw'
        else:
            window = self._take_estimate(pose, POSE_ESTIMATE_SIGMAS * np.sqrt(var))
            if self._info is not None:
                how = ('the next scan is matched from it' if window is None else
                       f'the next scans are searched within {window[0]:.2f} m and '
                       f'{window[1]:.2f} rad of it')
                self._info(f'pose estimate ({pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.2f}) '
                           f'taken: {how}')
            return []
        return [self._skip('pose estimate', None, f'at {record.stamp:.3f} s {why}',
                           'initial_pose')]

    def _localized_correction(self) -> Optional[np.ndarray]:
        """
        Return a copy of the correction (map from odometry) while localized, else None.

        Localized: the last scan matched, not lost, no ``wrong_start``, with odometry or TF
        poses (scan mode has no correction). What a pose estimate's tie-break and ``reset``
        on a saved map keep (the lock held).
        """
        m = self._last_match
        if (self.options.pose_source == 'scan' or m is None or not m.ok or self.lost
                or self.wrong_start):
            return None
        return self._correction.copy()

    def _restart(self, place: Optional[np.ndarray]) -> None:
        """
        Forget where the scans were (the lock held); the next scan starts at ``place``.

        ``place`` None: where its given pose (or scan mode's first prediction) puts it.
        """
        self._place = place
        self._spread = self._rearm = None
        self._last_match = None                 # (it made a restart look localized, an audit)
        self._tracked = None
        """The correction (map from odometry) of the scans matched before a pose estimate."""
        self._start_check = []
        self.wrong_start = None
        self._correction = np.zeros(3)
        self._gap = None
        self._recent.clear()
        self._recent_pose = None
        self._proposals.clear()
        self._shares.clear()
        self._anchor = self._anchor_at = self._anchor_step = self._odom_jump = None
        self._reset_window = None
        self._motion.clear()
        self._intervals.clear()
        self._found = False
        self._unmatched = None
        self._reckoned = None
        self._searched = None

    # -- producers -----------------------------------------------------------------------------
    def add(self, record) -> None:
        """Take one record; scans are checked and queued, pose data stored."""
        self.add_many((record,))

    def add_many(self, records: Iterable) -> None:
        """
        Take several records at once (one TFMessage: one lock).

        Raises TypeError / ValueError (one line, nothing of the batch taken) for what is no
        record (``_check_record``): a programming error, not bad data, which is counted and
        skipped.
        """
        records = list(records)
        for record in records:
            _check_record(record)
        notes = []
        with self._cv:
            for record in records:
                notes.extend(self._add(record))
            self._news = True
            self._cv.notify()
        for cause, text in notes:
            if self._warn is not None:
                self._warn(cause, text)

    def _add(self, record) -> list:
        """Take one record (the lock held); return the warnings it gives."""
        if isinstance(record, Scan):
            if self.options.scan_time_offset:
                record = replace(record, stamp=record.stamp + self.options.scan_time_offset)
            self.received += 1
            if (self.received - 1) % self.options.every:
                self.left_out += 1
                return []
            try:
                with np.errstate(invalid='ignore', over='ignore'):
                    check_scan(record.ranges, record.angle_min, record.angle_increment,
                               record.range_min, record.range_max, record.intensities,
                               angle_max=record.angle_max)
            except ScanError as exc:
                if (exc.cause == 'no_valid_ranges' and self._localizes_blind()
                        and self._blind_waiting() < self.options.max_waiting):
                    # A scan that sees nothing is a scan not matched all the same: posed in its
                    # turn, localized and skipped there (``_blind``). It does not hold back a
                    # partial group's flush (``idle_seconds``): that waits for usable scans;
                    # nor is it shed or counted for load (``_shed_waiting``).
                    idle = self._last_add
                    notes = self._add_scan(_Blind(**{f.name: getattr(record, f.name)
                                                     for f in fields(record)}, why=str(exc)))
                    self._last_add = idle
                    return notes
                return [self._skip('bad scan', exc.cause, str(exc))]
            return self._add_scan(record)
        if isinstance(record, Skipped):
            return [self._skip(f'undecodable message on {record.topic}', None, record.reason,
                               'undecodable')]
        if isinstance(record, PoseEstimate):
            if self.options.scan_matching:      # in its turn among the scans; else ignored
                self._waiting.append((record, None))
            return []
        try:
            with np.errstate(over='ignore', invalid='ignore'):
                note = self.poses.add(record)
        except RecordSkipped as exc:
            return [self._skip('pose data', exc.cause, str(exc))]
        if note is None:
            return []
        notes = [note]
        if note[0] == 'time_jump':
            self._scan_stamps.clear()       # the new time line's scans are not duplicates
            self._scan_steps.clear()
            notes.extend(self._release_leaps(True))     # judged against nothing now: taken
            if self.options.scan_matching and self._first_base is not None:
                # The odometry restarted with the clock (a bag played again, a simulation
                # reset): the correction map -> odom of the old time line would place the new
                # one's scans as far off as the old odometry had drifted.
                notes[0] = (note[0], f'{note[1]}; {self._search_from_start(record.stamp)}')
        return notes

    def _add_scan(self, record: Scan) -> list:
        """
        Take a checked scan, or hold it for a leap in its laser's stamps (``STAMP_LEAP``).

        Scans held before decide by this one: with it ``LEAP_CONFIRM`` scans on their time
        line are taken, in order; this one back on the old time line (nearer the newest stamp
        than the last held one) makes them misstamped scans, skipped (``stamp_order``).
        """
        frame, notes = record.frame_id, []
        if not math.isfinite(record.stamp):
            return [self._skip('bad scan', 'stamp_order', f'scan of frame {frame!r} stamped '
                               f'{record.stamp}: not a time')]
        held = self._leaps.get(frame)
        last = self._scan_stamps.get(frame)
        if held:
            if last is None or abs(record.stamp - held[-1][0].stamp) <= abs(record.stamp - last):
                held.append((record, self._now()))
                if len(held) >= LEAP_CONFIRM:
                    notes.extend(self._take_held(frame))
                return notes
            del self._leaps[frame]
            for scan, _ in held:
                notes.append(self._skip('bad scan', 'stamp_order', (
                    f'scan of frame {frame!r} stamped {scan.stamp:.3f}, '
                    f'{scan.stamp - last:+.1f} s from its newest scan, and the next came '
                    f'stamped {record.stamp:.3f}, on the old time line: a misstamped scan')))
        if last is not None and not (
                last - STAMP_LEAP <= record.stamp
                <= last + STAMP_LEAP + self._scan_steps.get(frame, 0.0)):
            if len(self._leaps) >= MAX_SCAN_FRAMES:
                notes.extend(self._take_held(next(iter(self._leaps))))
            self._leaps[frame] = [(record, self._now())]
            return notes
        return notes + self._take_scan(record)

    def _take_held(self, frame: str) -> list:
        """Take the scans of ``frame`` held for a leap (``_add_scan``), in order."""
        notes = []
        for scan, _ in self._leaps.pop(frame, ()):
            notes.extend(self._take_scan(scan))
        return notes

    def _release_leaps(self, final: bool) -> list:
        """
        Take the scans held for a leap that nothing more decides; return the warnings.

        At the end of input (``final``) all; live, those held longer than ``STAMP_LEAP`` and
        ``LEAP_CONFIRM`` + 1 of their laser's steps (the laser paused or stopped after them).
        """
        notes = []
        for frame in list(self._leaps):
            if not final:
                if self.clock is None:
                    break
                wait = max(STAMP_LEAP, (LEAP_CONFIRM + 1) * self._scan_steps.get(frame, 0.0))
                if self.clock() - self._leaps[frame][0][1] < wait:
                    continue
            notes.extend(self._take_held(frame))
        return notes

    def _take_scan(self, record: Scan) -> list:
        """Queue a checked scan for its pose (a duplicate stamp skipped); return the warnings."""
        last = self._scan_stamps.get(record.frame_id)
        jump = None
        if (self.options.pose_source == 'scan' and last is not None
                and record.stamp < last - TIME_JUMP_BACK):
            jump = self._scan_time_jump(record, last)
            last = None
        if last is not None and record.stamp == last:
            # Another scan of this laser at its newest stamp (a stuck clock, a duplicated
            # message): its pose would be the other scan's. Skipped, as pose data of that
            # kind; a scan stamped earlier still comes in its turn (late, out of order).
            return [self._skip('bad scan', 'stamp_order', (
                f'scan of frame {record.frame_id!r} stamped {record.stamp:.3f}, the same '
                'stamp as its newest scan (a stuck clock?)'))]
        if record.frame_id not in self._scan_stamps \
                and len(self._scan_stamps) >= MAX_SCAN_FRAMES:
            gone = next(iter(self._scan_stamps))
            self._scan_stamps.pop(gone)
            self._scan_steps.pop(gone, None)
        if last is not None and record.stamp > last:
            self._scan_steps[record.frame_id] = record.stamp - last
        self._scan_stamps[record.frame_id] = (record.stamp if last is None
                                              else max(record.stamp, last))
        now = self._now()
        self._last_add = now
        self._waiting.append((record, record.stamp if self.clock is None else now))
        return [] if jump is None else [jump]

    def _search_from_start(self, stamp: float) -> str:
        """
        After the clock jumped back: search for the next scans where the first scan was.

        Taken as a pose estimate at the first scan's robot pose, searched for within
        ``GAP_REACH`` and a full turn (``set_pose``): a recording played again from its start
        is found there; from elsewhere its scans are not mapped (no place explains them) until
        a pose estimate places them. Returns the words for the warning.
        """
        if self._first_base is None:
            return 'no scan mapped yet: mapped as the first'
        var = (np.array([GAP_REACH, GAP_REACH, math.pi]) / POSE_ESTIMATE_SIGMAS) ** 2
        self._waiting.append((PoseEstimate(stamp, self.map_frame, self._first_base.copy(),
                                           np.diag(var)), None))
        return 'searching for its scans where the first scan was'

    def _scan_time_jump(self, scan: Scan, newest: float) -> tuple:
        """
        Scan mode: ``scan`` is stamped ``TIME_JUMP_BACK`` or more before its laser's newest.

        The clock jumped back (a recording played again): the motion since the last scan means
        nothing and the robot is anywhere: searched for where the first scan was
        (``_search_from_start``). Returns the warning.
        """
        self._scan_stamps.clear()
        self._scan_steps.clear()
        where = self._search_from_start(scan.stamp)
        return ('time_jump', f'scan of frame {scan.frame_id!r} stamped {scan.stamp:.3f}, '
                f'{newest - scan.stamp:.1f} s before its newest: the clock jumped back; {where}')

    def skip(self, category: str, cause: str, text: str) -> None:
        """Count a record that is not used (e.g. a message the node could not convert)."""
        with self._lock:
            note = self._skip(category, cause, text)
        if self._warn is not None:
            self._warn(*note)

    def _skip(self, category: str, cause: Optional[str], text: str,
              warn_cause: str = None, count: int = 1) -> tuple:
        key = category if cause is None else f'{category}: {cause}'
        self.skipped[key] += count
        self.examples.setdefault(key, text)
        return warn_cause or cause, f'skipped {category}: {text}'

    # -- worker --------------------------------------------------------------------------------
    def wait(self, timeout: float) -> None:
        """Block until a record comes or ``timeout`` seconds pass (for a live worker)."""
        with self._cv:
            if not self._news:
                self._cv.wait(timeout)

    def _now(self) -> float:
        return self.poses.latest if self.clock is None else self.clock()

    def step(self, max_updates: Optional[int] = None) -> int:
        """Pose the queued scans, run the updates they complete (at most ``max_updates``)."""
        with self._lock:
            self._news = False
        return self._pose_and_run(False, False, max_updates)

    def queued_scans(self) -> int:
        """Return how many scans wait for their pose or their update (not mapped yet)."""
        with self._lock:
            return self._queued()

    def _queued(self) -> int:
        """``queued_scans`` with the lock held: waiting, ready, and held for a leap."""
        return (sum(isinstance(s, Scan) for s, _ in self._waiting) + len(self._ready)
                + sum(map(len, self._leaps.values())))

    def flush(self, final: bool = True) -> int:
        """
        Map the last, partial update group; at the end of input (``final``) give up waiting.

        Live, after a pause in the scans, the node flushes with ``final=False``: scans still
        waiting for their pose keep waiting (up to ``wait``). Returns the number of update
        groups processed.
        """
        return self._pose_and_run(final, True)

    def _pose_and_run(self, final: bool, partial: bool, max_updates: int = None) -> int:
        """
        Pose the queued scans and run their updates, again until none runs; return the updates.

        Again: with scan matching a group is posed only once the ones before it ran
        (``_pose_waiting``). At most ``max_updates`` (None: no limit).
        """
        done = 0
        while True:
            notes = self._pose_waiting(final=final)
            ran = self._run(None if max_updates is None else max_updates - done, partial,
                            shed=not final)
            self._emit(notes)
            done += ran
            if not ran or (max_updates is not None and done >= max_updates):
                return done

    def idle_seconds(self) -> float:
        """Seconds (of the clock) since the last scan came; inf before any."""
        with self._lock:
            return math.inf if self._last_add is None else self._now() - self._last_add

    def has_partial_group(self) -> bool:
        """Whether posed scans wait for the rest of their group."""
        with self._lock:
            return 0 < len(self._ready) < self.options.update_every_n_scans

    def _emit(self, notes) -> None:
        if self._warn is not None:
            for cause, text in notes:
                self._warn(cause, text)

    def _pose_waiting(self, final: bool) -> list:
        notes = []
        opts = self.options
        with self._lock:
            notes.extend(self._release_leaps(final))    # held for a leap in their stamps
            now = self._now()
            # At the end of input (the node's shutdown save maps the queued scans) nothing is
            # shed: those scans are mapped, however late.
            if opts.scan_matching and not final:
                notes.extend(self._shed_waiting(now))
            blind = self._blind_waiting()       # (not counted against max_waiting)
            while self._waiting:
                if opts.scan_matching and len(self._ready) >= opts.update_every_n_scans:
                    # A scan is matched against the map of every scan before it, as in a
                    # replay: not against a map that lags behind because updates do.
                    break
                scan, arrived = self._waiting[0]
                if isinstance(scan, PoseEstimate):
                    self._waiting.popleft()
                    notes.extend(self._estimate(scan))
                    continue
                give_up = (final or len(self._waiting) - blind > opts.max_waiting
                           or now - arrived >= opts.wait)
                if (scan.pose is None and not give_up and math.isfinite(self.poses.latest)
                        and self.poses.newest(scan) < scan.stamp):
                    break           # pose data at or after the scan's stamp may still come
                if not give_up and not self._last_beam_posed(scan):
                    break           # motion compensation: the last beam's pose may still come
                try:
                    pose = self.poses.pose(scan)
                except TransformLookupError as exc:
                    if exc.curable and not give_up:
                        break       # keep the order: later scans wait behind this one
                    self._waiting.popleft()
                    notes.extend(self.poses.held_notes())
                    if isinstance(scan, _Blind):    # unusable first: skipped as it was
                        blind -= 1
                        notes.append(self._skip('bad scan', 'no_valid_ranges', scan.why))
                        continue
                    notes.append(self._skip('no pose', exc.cause,
                                            f'frame {scan.frame_id!r} at {scan.stamp:.3f}: '
                                            f'{exc}'))
                    continue
                self._waiting.popleft()
                blind -= isinstance(scan, _Blind)
                notes.extend(self.poses.held_notes())
                notes.extend(self.poses.rate_notes(scan.stamp, scan.frame_id))
                notes.extend(self.poses.flip_notes())
                notes.extend(self._convert(scan, pose, arrived))
            if opts.max_queue is not None and not final:
                while len(self._ready) > opts.max_queue:
                    self._ready.popleft()
                    notes.append(self._dropped('queue_full'))
        return notes

    def _blind_waiting(self) -> int:
        """Return how many scans with no usable reading wait for their pose (``_Blind``)."""
        return sum(isinstance(s, _Blind) for s, _ in self._waiting)

    def _shed_waiting(self, now: float) -> list:
        """
        Scan matching: load shedding (max_queue, max_latency) on the scans not yet posed.

        Scans with no usable reading (``_Blind``) are neither counted nor shed: they cost a
        pose, and shed, they would be told as dropped for load where the laser saw nothing.
        """
        opts, notes = self.options, []
        scans = [i for i, (s, _) in enumerate(self._waiting)
                 if isinstance(s, Scan) and not isinstance(s, _Blind)]
        drop = set()
        if opts.max_queue is not None and len(scans) > opts.max_queue:
            drop.update(scans[:len(scans) - opts.max_queue])
            notes += [self._dropped('queue_full') for _ in range(len(drop))]
        if opts.max_latency is not None and self.clock is not None:
            keep = opts.update_every_n_scans
            late = [i for i in scans[:max(len(scans) - keep, 0)] if i not in drop
                    and now - self._waiting[i][1] > opts.max_latency]
            drop.update(late)
            notes += [self._dropped('too_late') for _ in late]
        if drop:
            self._waiting = deque(w for i, w in enumerate(self._waiting) if i not in drop)
        return notes

    def _last_beam_posed(self, scan: Scan) -> bool:
        """Whether the pose data covers the scan's last beam (or none is needed or can come)."""
        span = beam_span(scan)
        if span == 0.0 or scan.pose is not None or self.options.pose_source == 'scan':
            return True
        try:
            self.poses.pose(scan, scan.stamp + span, tolerance=0.0)
        except TransformLookupError as exc:
            return exc.cause != 'too_new'
        return True

    def _convert(self, scan: Scan, pose: PlanarPose, arrived: float) -> list:
        t0 = time.perf_counter()
        low = max(float(scan.range_min), self.mapper.config.min_mapping_range)
        limit = min(float(scan.range_max), self.mapper.config.max_mapping_range)
        notes = []
        xyz, base, beams = pose.xyz, None, None
        scan_mode = self.options.pose_source == 'scan'
        try:
            with np.errstate(invalid='ignore', over='ignore'):
                angles = pose.beam_angles(scan.angles())
                start, window, estimate = None, None, None
                rearmed = None
                if self._rearm is not None:     # blind scans since an estimate (``_blind``)
                    if self._place is None:
                        rearmed = self._rearm
                        self._place = _compose(self._correction,
                                               self.poses.robot_pose(scan, pose))
                        self._spread = self._rearm_window(rearmed)
                    self._rearm = None
                placing = self._place, self._spread
                if self._place is not None:     # the first scan on a loaded map, an estimate
                    if scan_mode:               # no given pose: predicted at the place itself
                        start, self._correction = np.array(self._place, dtype=np.float64), \
                            np.zeros(3)
                    else:
                        self._correction = _compose(
                            self._place, _inverse(self.poses.robot_pose(scan, pose)))
                    window, self._spread = self._spread, None
                    if window is not None and not len(self.mapper.segments):
                        window = None           # nothing to search on: placed, as at a start
                    estimate = None if window is None else self._place
                    self._place = None
                if scan_mode:
                    xyz = self._predict(scan.stamp) if start is None else start
                    if start is None:
                        window = self._gap_window(scan.stamp)
                    self._quiet = (None if self._last_scan is None
                                   else scan.stamp - self._last_scan)
                    self._last_scan = scan.stamp
                if window is None and self._gap is not None:
                    window = self._gap.window   # searched for still (after a gap, an estimate)
                motion = self._beam_motion(scan, pose, notes, angles, (low, limit))
                if motion is not None:
                    local = beam_points(scan.ranges, angles, motion, low, limit)
                if self.options.scan_matching:
                    if motion is None:      # (the readings checked once for both poses)
                        beams = usable_beams(scan.ranges, angles, low, limit)
                        local = beams_to_points(*beams, np.zeros(3))
                    if len(local):
                        before, self._last_match = self._correction, None
                        given = xyz
                        base = self.poses.robot_pose(scan, pose)
                        xyz, note = self._match(local, xyz, base, (scan.stamp, window,
                                                                   estimate))
                        if self._deskew is not None:    # placed again from the match's motion
                            local = self._deskew.local()
                        notes += [note] if note is not None else []
                        notes += self._localize(scan.stamp, given, xyz, before, scan.frame_id)
                        m = self._last_match
                        if self._gap is not None and (m is None or not m.ok):
                            where = ('near the pose estimate' if self._gap.estimate is not None
                                     else 'after the odometry came back near its origin (since '
                                     f'{self._gap.since:.3f} s)' if self._gap.reset
                                     else f'after a gap in the scans since {self._gap.since:.3f} s'
                                     if self._gap.paused else 'after scans that did not match '
                                     f'since {self._gap.since:.3f} s')
                            self._skip('not mapped', 'lost', f'the scan at {scan.stamp:.3f} s: '
                                       f'not found {where}')
                            return notes
                        if self.matched_scans is not None and m is not None and m.ok:
                            self.matched_scans.append((scan.stamp, xyz, local,
                                                       self._correction.copy()))
                        if self._proposals and (m is None or not m.ok):
                            # lost: the scans say the prediction is wrong, and where the robot
                            # is instead is not confirmed. Mapped nowhere, no motion.
                            why = m.reason if m is not None else 'no map near the prediction'
                            self._skip('not mapped', 'lost', f'the scan at {scan.stamp:.3f} s: '
                                       f'{why} after a refused jump')
                            return notes
                    elif self._localizes_blind():
                        # An estimate to search around: at the next scan, moved by the odometry
                        # as the correction just set from it moves this one.
                        if placing[0] is not None:
                            self._rearm = placing[1] if rearmed is None else rearmed
                        return notes + self._blind(scan, xyz)
                if motion is not None:
                    pts = transform(local, xyz)
                elif beams is not None:
                    pts = beams_to_points(*beams, xyz)
                else:
                    pts = scan_to_points(scan.ranges, angles, xyz, low, limit)
        except ValueError as exc:
            return [self._skip('bad scan', 'bad_geometry', str(exc))]
        if len(pts) == 0:
            return [self._skip('bad scan', 'no_valid_points',
                               f'no reading within the mapping range at {scan.stamp:.3f} s')]
        notes += self._check_self_hits(scan, xyz, low)
        if self._motion and scan.stamp <= self._motion[-1][0]:
            self._motion.clear()            # time went back: the old motion means nothing
            self._intervals.clear()
        if self._motion:
            self._intervals.append(scan.stamp - self._motion[-1][0])
        self._motion.append((scan.stamp, xyz))
        if self.options.keep_points or self.options.scan_matching:
            # The robot base (the frame the laser is mounted on), where the laser went.
            if base is None:
                base = self.poses.robot_pose(scan, pose)
            mount_to_base = _compose(_inverse(pose.xyz), base)
            row = _compose(xyz, mount_to_base)
            self._trajectory.append((scan.stamp, row[0], row[1], float(wrap_angle(row[2]))))
            if self._first_base is None:
                self._first_base = np.array([row[0], row[1], float(wrap_angle(row[2]))])
        if self._loaded is not None and len(self._start_check) < START_CHECK[0]:
            notes += self._check_start(pts, xyz[:2])
        self._ready.append((scan, pts, xyz[:2], time.perf_counter() - t0, arrived))
        return notes

    def _rearm_window(self, spread: tuple) -> tuple:
        """
        Return the window (m, rad) to search an estimate's ``spread`` in after blind scans.

        The odometry carried the estimate over them: its error since (``_reckon``, from the
        first of them), ``POSE_ESTIMATE_SIGMAS`` standard deviations, is added (in quadrature)
        to the estimate's own, at most ``GAP_REACH`` and half a turn. Searched within the
        estimate's spread alone, 100 blind scans after an estimate of 0.6 m left the robot
        1.9 m off and the search gave up (a review).
        """
        radius, turn = spread
        if self._reckoned is not None:
            shift, yaw = self._reckoned_reach()
            radius, turn = math.hypot(radius, shift), math.hypot(turn, yaw)
        return min(radius, GAP_REACH), min(turn, math.pi)

    def _reckoned_reach(self) -> tuple:
        """
        Return ``POSE_ESTIMATE_SIGMAS`` standard deviations (m, rad) of ``_reckoned``'s error.

        The position's along its worst direction, the heading's; ``_reckoned`` must be set.
        """
        cov = self._reckoned[0]
        sd = math.sqrt(max(float(np.linalg.eigvalsh(cov[:2, :2]).max()), 0.0))
        return POSE_ESTIMATE_SIGMAS * sd, POSE_ESTIMATE_SIGMAS * math.sqrt(max(cov[2, 2], 0.0))

    def _localizes_blind(self) -> bool:
        """Whether a scan with no usable reading is localized before it is skipped (``_blind``)."""
        return self.options.scan_matching and self.options.pose_source != 'scan'

    def _blind(self, scan: Scan, given: np.ndarray) -> list:
        """
        Scan matching from odometry or TF: a scan with no reading to match; return the warnings.

        The laser covered, or nothing within its range or the mapping range: no match, so a
        scan not matched (``_localize``: the odometry's pose, its error since the last match
        added to the covariance, published like any other, so map -> odom goes on as AMCL
        republishes it per scan; on a saved map it counts toward ``UNMATCHED_STREAK``), then
        skipped as a bad scan, nothing mapped. Skipped before they were posed (until
        2026-12-02), 3 s of such scans on the drifted office drive left the robot 0.27 m off,
        matched, to the end (``benchmarks/blocked_laser.py``, 'none'), and in mapping nothing
        was published while the laser saw nothing. A pose estimate or initial pose before it
        sets the correction as at any first scan, and its search waits for the next scan, moved
        there by the odometry, its window widened by the odometry's error (``_rearm``,
        ``_rearm_window``; restored as it was, the pose stood at the estimate while the robot
        drove, a review). The scan before stays the last match until the session is not
        localized (a reset after one such scan keeps the pose). Such scans are not load
        (``_shed_waiting``), and one whose pose cannot come is skipped as unusable, as before.
        Scan mode has no odometry to carry the pose: its scans are skipped when they come and
        the time without them is a gap (``GAP_SECONDS``).
        """
        notes = self._localize(scan.stamp, given, _compose(self._correction, given),
                               self._correction, scan.frame_id, blind=True)
        if self.unmatched is not None:      # not localized now: the last match says no more
            self._last_match = None
        if isinstance(scan, _Blind):
            return notes + [self._skip('bad scan', 'no_valid_ranges', scan.why)]
        return notes + [self._skip('bad scan', 'no_valid_points', 'no reading within the '
                                   f'mapping range at {scan.stamp:.3f} s')]

    def _check_self_hits(self, scan: Scan, pose: np.ndarray, low: float) -> list:
        """
        Follow the scan's short readings (``scan.SelfHits``); warn of any moving with the robot.

        ``pose``: where the scan was placed; ``low``: the lowest range mapped. The warning names
        the laser, its sectors (degrees, in the laser's own frame) and their ranges, and the
        setting that leaves them out.
        """
        hits = self._self_hits.pop(scan.frame_id, None) or SelfHits()
        self._self_hits[scan.frame_id] = hits      # (the newest last)
        while len(self._self_hits) > SELF_HIT_FRAMES:
            del self._self_hits[next(iter(self._self_hits))]
        found = hits.add(scan.ranges, pose, low)
        if not found.any():
            return []
        where = ', '.join(f'{np.degrees(a):.0f}' if a == b else
                          f'{np.degrees(min(a, b)):.0f}..{np.degrees(max(a, b)):.0f}'
                          for a, b in sectors(scan.angles(), found))
        r = np.asarray(scan.ranges, dtype=np.float64)[found]
        return [('self_hits', f'laser {scan.frame_id!r}: {int(found.sum())} reading(s) at '
                 f'{where} deg kept their range ({r.min():.2f}-{r.max():.2f} m) while the laser '
                 f'drove {SELF_HIT_MOTION[0]:g} m and turned {np.degrees(SELF_HIT_MOTION[1]):.0f} '
                 f'deg in place: something that moves with the robot '
                 f'(a part of it, or someone walking with it) is mapped as walls along its path; '
                 f'set incremental.min_mapping_range to {r.max() + SELF_HIT_TOLERANCE:.2f} m '
                 f'(their readings and {SELF_HIT_TOLERANCE:g} m of noise), or filter those '
                 f'angles out of the scan')]

    def _check_start(self, pts: np.ndarray, origin: np.ndarray) -> list:
        """``START_CHECK``: one more scan placed on the loaded map; the warning, if it is due."""
        saved = self._loaded[0].segments
        self._start_check.append(float(passing_beams(saved, origin, pts).mean()) if len(saved)
                                 else 0.0)
        if len(self._start_check) < START_CHECK[0]:
            return []
        share = float(np.median(self._start_check))
        if share <= START_CHECK[1]:
            return []
        self.wrong_start = share
        return [('wrong_start', f'localizing on the saved map, the beams of the first '
                 f'{len(self._start_check)} scans pass through its walls ({100 * share:.0f} % '
                 f'of them, median): the scans are likely matched onto a wrong place; give the '
                 "robot's pose (initial_pose, --initial-pose, or a pose estimate on "
                 'initialpose)')]

    def _predict(self, stamp: float) -> np.ndarray:
        """
        Scan mode: the given pose whose correction is the constant-velocity prediction.

        The prediction is the last pose moved on by the last motion (``extrapolate``), the
        origin for the first scan; returned as ``correction^-1 * prediction`` so that the
        matcher's prediction (correction * given) is it.
        """
        if not self._motion:
            return _inverse(self._correction)
        return _compose(_inverse(self._correction), extrapolate(self._motion, stamp))

    def _gap_limit(self) -> float:
        """Scan mode: seconds without a posed scan that make a gap (see ``_gap_window``)."""
        limit = GAP_SECONDS
        if self._intervals:
            limit = max(limit, GAP_FACTOR * _median(self._intervals))
        return limit

    def _gap_window(self, stamp: float) -> Optional[tuple]:
        """
        Scan mode: (m, rad) around the prediction to search when the scan comes after a gap.

        A gap: more than ``GAP_SECONDS`` and ``GAP_FACTOR`` times the median interval of the
        last posed scans since the last posed scan (or lost after one); None when there is
        none. The window grows with the gap at ``GAP_SPEED`` and ``GAP_TURN_RATE`` (or the
        speeds before it), the heading up to half a turn.
        """
        if not self._motion:
            return None
        t1 = self._motion[-1][0]
        elapsed = stamp - t1
        if not (elapsed > self._gap_limit() or self._gap is not None):
            return None
        v = motion_velocity(self._motion, t1)
        v = np.zeros(3) if v is None else np.abs(v)
        elapsed = max(elapsed, 0.0)
        return (max(GAP_SPEED, math.hypot(v[0], v[1])) * elapsed,
                min(math.pi, max(GAP_TURN_RATE, v[2]) * elapsed))

    def _beam_motion(self, scan: Scan, pose: PlanarPose, notes: list, angles: np.ndarray,
                     limits: tuple) -> Optional[np.ndarray]:
        """
        Return each beam's laser pose relative to the pose at the stamp, (B, 3), or None.

        None when the scan's beams are taken at once (``time_increment`` 0) or no motion is
        known. From the pose source (first, middle and last beam, interpolated between them)
        unless in scan mode or when it has no pose at those times; else the matched motion
        (``_deskew`` then holds it, for ``_match`` to place the beams again from its result;
        ``angles`` and ``limits``, the beams' angles and the mapping range limits (lowest,
        highest), are for it).
        """
        self._deskew = None
        span = beam_span(scan)
        if span == 0.0:
            ti = scan.time_increment
            if ti is not None and ti != 0 and len(scan.ranges) > 1:
                notes.append(('time_increment', f'time_increment {ti!r} s ignored (no motion '
                              'compensation): expected 0, or > 0 with the beams spanning at '
                              f'most {MAX_SCAN_SPAN:g} s'))
            return None
        n = len(scan.ranges)
        times = float(scan.time_increment) * np.arange(n)
        knots = np.array([0.0, 0.5 * span, span])
        rel = None
        if self.options.pose_source != 'scan':
            try:
                at = np.array([self.poses.pose(scan, scan.stamp + k).xyz for k in knots[1:]])
                rel = _compose(_inverse(pose.xyz), at)
            except TransformLookupError:
                rel = None
            if rel is not None and self._jumps_within(rel[-1], span):
                rel = None                  # the odometry jumped during the scan
        if rel is None:
            velocity = motion_velocity(self._motion, scan.stamp)
            if velocity is None:
                return None
            self._deskew = _Deskew(scan, self._motion[-1], velocity, times, span, angles,
                                   limits)
            return self._deskew.motion
        return sweep_motion(times, span, rel)

    def _jumps_within(self, motion: np.ndarray, span: float) -> bool:
        """
        Whether the pose source moves the laser by ``motion`` within one scan only by a jump.

        Beyond ``ODOM_JUMP`` more than the pace of the last matched scans (the base's: the
        laser's differs by its mount turning, centimetres) the beams of a scan during which the
        odometry was reset would be spread along the jump (measured with a moving sensor and the
        odometry reset mid-drive: walls F1 0.79 on the simulated office, 0.24 on the
        corridors); placed with the matched motion instead.
        """
        pace = 0.0
        if self._anchor_step is not None and self._anchor_step[1] > 0:
            step, seconds = self._anchor_step
            pace = math.hypot(step[0], step[1]) * span / seconds
        return math.hypot(motion[0], motion[1]) - pace > max(ODOM_JUMP[0], ODOM_JUMP[1] * span)

    def _keyframe(self, local: np.ndarray, pose: np.ndarray) -> None:
        """
        Keep the scan's chords for the next matches when it moved far enough from the last kept.

        A scan 2.5 cm (40 Hz) from the one before sees the same as it: matched to each other,
        their small errors would add up scan after scan (a perfect odometry drifted 0.25 m over
        2400 scans so); matched to keyframes ``KEYFRAME_STEP`` apart they add up per keyframe.
        """
        if not far_enough(self._recent_pose, pose):
            return
        self._recent.add(transform(local, pose), pose)
        self._recent_pose = np.asarray(pose, dtype=np.float64).copy()

    def _match(self, local: np.ndarray, given: np.ndarray, base: np.ndarray,
               gap: tuple = (None, None, None)) -> tuple:
        """
        Refine ``given`` (the pose TF or odometry gives) against the map; (pose, note).

        ``gap``: the scan's stamp; after a gap (scan mode) or a pose estimate (``set_pose``),
        the window (m, rad) around the prediction where the pose is searched instead
        (``_find_after_gap``; None: matched from the prediction); the estimate's base pose
        (None after a gap).

        ``base``: the robot base's pose, as given (the odometry's motion is the base's). With
        TF or odometry, the prediction's covariance is the odometry's over the base's motion
        since the last matched scan (``odometry_covariance``, and ``TURN_SLIP`` per radian turned
        on each axis): the matcher holds a weakly constrained direction at the prediction when
        the match disagrees beyond it and the established walls (support >=
        ``ESTABLISHED_SUPPORT``) do not carry it (``core.register.WEAK_SIGMAS``): a person
        walking ahead in a corridor.
        """
        local = spread(local, MATCH_POINTS)
        stamp, window, estimate = gap
        step = self._odometry_jumped(local, given, base, stamp, window)
        prediction = _compose(self._correction, given)
        reset = self._reset_window is not None
        if reset:                       # searched around where the last pace leads
            window, self._reset_window = self._reset_window, None
            prediction = self._reset_at
        cov = None
        if self.options.pose_source != 'scan' and self._anchor is not None:
            if step is None:
                step = _compose(_inverse(self._anchor), base)
            cov = odometry_covariance(step)
            slip = TURN_SLIP * abs(math.remainder(float(step[2]), 2.0 * math.pi))
            cov[:2, :2] += np.diag([slip * slip, slip * slip])
        sigma = self.mapper.sigma
        segs = self.mapper.segments if sigma is not None else np.zeros((0, 2, 2))
        support = self.mapper.support if sigma is not None else np.zeros(0)
        sigma = sigma or MATCH_SIGMA
        recent, transient = self._recent.chords(), self._recent.transient()
        if window is not None:
            return self._find_after_gap(local, given, prediction, np.concatenate([segs, recent]),
                                        sigma, window, base, stamp, estimate, reset)
        world = transform(local, prediction)
        reach = 0.5 + self.mapper.r
        lo, hi = world.min(axis=0) - reach, world.max(axis=0) + reach
        inside = [in_box(s, lo, hi) for s in (segs, recent)]   # near the predicted scan
        segs, recent, support = (np.compress(inside[0], segs, axis=0),
                                 np.compress(inside[1], recent, axis=0),
                                 np.compress(inside[0], support))
        transient = np.compress(inside[1], transient)
        if LOST_WITHOUT_CHORDS and self._proposals and len(segs):
            recent, transient = recent[:0], transient[:0]   # lost: the map alone, if any here
        if not len(segs) and not len(recent):
            self.matches['no map yet'] += 1
            if not self._proposals and not self._fixed():   # (lost: not where the map is)
                self._keyframe(local, prediction)
                self._set_anchor(base, stamp, prediction)
            return prediction, None
        if MATCH_SEEN_THROUGH and self.options.pose_source != 'scan':
            segs, support, recent, kept = _not_seen_through(
                segs, support, recent, prediction[:2], world,
                self.mapper.config.smemsf.kappa * sigma)
            transient = transient[kept]
        near = np.concatenate([segs, recent])
        degenerate = guard = MATCH_DEGENERATE[self.options.pose_source]
        starts = prior = None
        if self.options.pose_source == 'scan' and stamp is not None and self._motion:
            t1 = self._motion[-1][0]
            starts = np.array([extrapolate(self._motion, t1 + k * (stamp - t1))
                               for k in SCAN_MOTION_SHARES])
            step = _compose(_inverse(self._motion[-1][1]), extrapolate(self._motion, stamp))
            sd = (max(math.hypot(step[0], step[1]), SCAN_PRIOR[0]),
                  max(abs(math.remainder(float(step[2]), 2.0 * math.pi)), SCAN_PRIOR[1]))
            prior = np.diag([sd[0] ** 2, sd[0] ** 2, sd[1] ** 2])
            guard = 0.0                 # the prior keeps weak directions near the start
        last = self._last_match         # where the newest chords were placed (its covariance)
        terms = {'prediction_cov': cov, 'prediction_prior': prior,     # both matches' terms
                 'established': np.concatenate([support >= ESTABLISHED_SUPPORT,
                                                np.zeros(len(recent), dtype=bool)]),
                 'transient': np.concatenate([np.zeros(len(segs), dtype=bool), transient]),
                 'chords': np.arange(len(near)) >= len(segs),
                 'chord_cov': None if last is None else last.covariance}
        m = match_scan(local, prediction, near, sigma, degenerate=guard, starts=starts,
                       relocalize=RELOCALIZE, relocalize_share=self._relocalize_share(),
                       relocalize_near=prior is not None, **terms)
        for _ in range(DESKEW_ROUNDS if self._deskew is not None and m.ok else 0):
            again = self._deskew.propose(m.pose)
            if again is None:
                break
            placed = spread(again, MATCH_POINTS)
            m2 = match_scan(placed, prediction, near, sigma, degenerate=guard,
                            starts=np.asarray(m.pose, dtype=np.float64)[None], **terms)
            if not m2.ok:
                break
            self._deskew.accept()
            m, local = m2, placed
        lost = bool(self._proposals)
        if m.reason == 'correction too large':
            m = self._confirm(local, given, m, near, sigma, degenerate)
        elif m.ok:
            self._proposals.clear()
        if self.unmatched is not None:      # not localized: only a search ends it
            found = self._search_reckoned(local, prediction, sigma, stamp)
            if found is not None:
                m = found
                self._proposals.clear()
            elif m.ok:
                m = m._replace(ok=False, reason='not localized', pose=prediction,
                               covariance=_PRIOR, proposal=None, relocalized=False)
        self._found = lost and m.ok
        self._last_match = m
        if not m.ok:
            self.matches[m.reason] += 1
            if m.reason == 'too few inliers' and not self._proposals and not self._fixed():
                self._keyframe(local, prediction)  # new ground: the prediction is all there is
            kept = '; the scan is not mapped' if self._proposals else ''
            return prediction, ('match_failed', f'scan matching kept the predicted pose: '
                                f'{m.reason} ({m.inliers} inliers){kept}')
        self.matches['relocalized' if m.relocalized else 'matched'] += 1
        self.held += m.held > 0
        self._set_anchor(base, stamp, m.pose)
        self._shares.append(m.share)
        if not self._fixed() or m.share >= ANCHOR_SHARE:
            self._keyframe(local, m.pose)
        self._correction = _compose(m.pose, _inverse(given))
        return m.pose, None

    def _fixed(self) -> bool:
        """Whether the session localizes on a saved map it never changes, from odometry or TF."""
        return (self._loaded is not None and not self.options.mapping
                and self.options.pose_source != 'scan')

    def _set_anchor(self, base, stamp, pose) -> None:
        """
        Note the last matched scan: its base pose (given), stamp and laser pose; the step.

        The step into a scan where the odometry jumped is no pace (``_odometry_jumped``):
        the pace stays as that judgement left it (none when the odometry was followed or
        kept; the trial motion whose match was taken when map -> odom was re-anchored).
        """
        base = np.asarray(base, dtype=np.float64).copy()
        if (self._odom_jump is None and self._anchor is not None and stamp is not None
                and self._anchor_at is not None and self._anchor_at[0] is not None):
            self._anchor_step = (_compose(_inverse(self._anchor), base),
                                 stamp - self._anchor_at[0])
        self._anchor = base
        self._anchor_at = (stamp, np.asarray(pose, dtype=np.float64).copy())

    def _odometry_jumped(self, local: np.ndarray, given: np.ndarray, base: np.ndarray, stamp,
                         window) -> Optional[np.ndarray]:
        """
        Judge an odometry jump; return the base motion the prediction carries then, or None.

        An odometry driver that restarts (its pose back to 0 while the robot drives on) or a
        slip moves the odometry frame under the robot. Predicted from it, the scans were
        matched onto copies of the map shifted by the jump (measured: sim:office reset at scan
        150, poses 16.6 m off, walls F1 0.65), or searched for within 1 m only. The odometry's
        motion since the last matched scan is judged against its previous step, carried on at
        that pace (constant velocity; neither may span more than ``MAX_MOTION_GAP``; after a
        re-anchored jump, the trial motion taken there): off by
        more than ``ODOM_JUMP`` (or its heading by more than ``ODOM_JUMP_TURN``), the scan is
        matched (``_trial_match``) from both: from where the pace puts the robot (or that pace
        without its turn, or standing still: whichever the scan fits best), and from where the
        odometry does (a recording played again with ``play --loop``, a simulation's robot
        moved: the scans jumped with the odometry). The odometry is followed unless a pace's
        match explains clearly more of the scan (``ODOM_JUMP_MARGIN``), and kept when no
        pace's match is taken; else map -> odom is re-anchored where the pace's match put the
        scan. ``_localize`` warns either way, except of a turn alone that is followed or kept.
        A turn of more than the matcher's heading search (0.2 rad) in the step the odometry
        jumped over is lost with it (the simulated drives' instant U-turns).
        """
        if (self.options.pose_source == 'scan' or self._anchor is None or window is not None
                or stamp is None or self._anchor_at is None or self._anchor_at[0] is None):
            return None
        dt = stamp - self._anchor_at[0]
        step = _compose(_inverse(self._anchor), base)
        pace = np.zeros(3)
        if (self._anchor_step is not None and 0 < self._anchor_step[1] <= MAX_MOTION_GAP
                and dt > 0):
            pace = self._anchor_step[0] * (dt / self._anchor_step[1])
        shift, dt = math.hypot(step[0] - pace[0], step[1] - pace[1]), max(dt, 0.0)
        turn = abs(wrap_angle(float(step[2] - pace[2])))
        origin = (math.hypot(base[0], base[1]) <= ODOM_RESET_REACH
                  and abs(wrap_angle(float(base[2]))) <= ODOM_JUMP_TURN[0])
        if dt > MAX_MOTION_GAP:
            return self._reset_after_gap(local, given, base, step, dt, origin)
        moved = shift > max(ODOM_JUMP[0], ODOM_JUMP[1] * dt)
        reset = (origin and shift > ODOM_RESET_SHIFT
                 and turn > max(ODOM_JUMP_TURN[0], ODOM_JUMP_TURN[1] * dt))
        if not moved and not reset:
            return None
        mount = _compose(_inverse(base), given)          # the laser on the base
        was = _compose(self._anchor_at[1], _inverse(mount))     # the base, last matched
        # The pace, the pace without its turn (it may have been a turn's last step), and
        # standing still (a robot that stopped): the first whose match is taken, unless a
        # later one explains clearly more.
        paces = [pace, np.array([pace[0], pace[1], 0.0]), np.zeros(3)]
        best, paced = pace, None
        for motion in paces:
            m = self._trial_match(local, _compose(was, _compose(motion, mount)))
            if m is not None and m.ok and (
                    paced is None or m.share > paced.share + ODOM_JUMP_MARGIN):
                best, paced = motion, m
        followed = self._trial_match(local, _compose(self._correction, given))
        if paced is None or (followed is not None and followed.ok
                             and followed.share + ODOM_JUMP_MARGIN >= paced.share):
            # The odometry is kept: its match fits better, or no pace fits (nothing to
            # re-anchor on). A turn alone is motion then (ODOM_JUMP_TURN): nothing changes.
            # Else its step is no pace for the next scans (a jump, or a pace that was wrong:
            # after a gap, a turn).
            if not moved:
                return None
            self._odom_jump = (shift, turn, dt, 'followed' if followed is not None
                               and followed.ok else 'kept', None)
            self._anchor_step = None
            self._anchor = np.asarray(base, dtype=np.float64).copy()    # (judged once)
            self._anchor_at = (stamp, _compose(self._correction, given))
            return step
        self._correction = _compose(paced.pose, _inverse(given))
        self._anchor = np.asarray(base, dtype=np.float64).copy()
        self._anchor_at = (stamp, np.asarray(paced.pose, dtype=np.float64).copy())
        self._odom_jump = (shift, turn, dt, 'anchored', None)
        if dt > 0:
            # The trial motion whose match was taken is the pace on (its start, not the match's
            # refined motion): a kept pace with a turn the scan did not fit (an instant turn
            # before the jump) would turn again at every later judgement (a node that fell
            # behind judged a second jump 0.4 s on: 113 deg off that pace).
            self._anchor_step = (np.asarray(best, dtype=np.float64).copy(), dt)
        return best

    def _reset_after_gap(self, local: np.ndarray, given: np.ndarray, base: np.ndarray,
                         step: np.ndarray, dt: float, origin: bool) -> None:
        """
        Judge odometry back near its origin after ``dt`` s without a matched scan (a gap).

        A driver that restarts is silent for a while (its scans refused, ``odom_gap``), then
        back at its origin: no pace carries over the gap, and predicted from it the scans
        were matched onto a copy of the map (the simulated office, odometry silent for 1.5 s
        and then reset: 13 m RMS, walls F1 0.49). When the odometry says the robot moved more
        than ``ODOM_JUMP[0]`` since the last matched scan into a pose near its origin
        (``origin``; a turn alone is not enough: a helper audit's robot, 0.3 m from where its
        odometry started, turned 93 deg in a 1.3 s silence and saw new ground, its odometry's
        match 0.66 of the scan against 0.85 needed, and the session gave up for the rest of
        the drive), and its own prediction does not put the scan on the map as well as the
        matches before it (``GAP_SHARE``), the scan is searched for on the map around where
        the last pace leads (``_reset_at``, ``_reset_window``: within ``GAP_SPEED``, or the
        speed before, times the gap, as in scan mode after a gap; ``_find_after_gap``).
        """
        if not origin or math.hypot(step[0], step[1]) <= ODOM_JUMP[0]:
            return None
        followed = self._trial_match(local, _compose(self._correction, given))
        if followed is not None and followed.ok and followed.share >= self._gap_share():
            return None                 # the robot came back near the origin: motion
        speed, rate, motion = GAP_SPEED, GAP_TURN_RATE, np.zeros(3)
        v = motion_velocity(self._motion, self._motion[-1][0]) if self._motion else None
        if v is not None:           # the placed scans' (a late odometry may step by nothing)
            speed, rate = max(speed, math.hypot(v[0], v[1])), max(rate, abs(v[2]))
        if self._anchor_step is not None and 0 < self._anchor_step[1] <= MAX_MOTION_GAP:
            pace, seconds = self._anchor_step
            speed = max(speed, math.hypot(pace[0], pace[1]) / seconds)
            rate = max(rate, abs(wrap_angle(float(pace[2]))) / seconds)
            motion = pace * (dt / seconds)          # the robot drove on at its pace
        mount = _compose(_inverse(base), given)    # the laser on the base
        self._reset_at = _compose(_compose(self._anchor_at[1], _inverse(mount)),
                                  _compose(motion, mount))
        self._reset_window = (speed * dt, min(math.pi, rate * dt))
        self._odom_jump = (math.hypot(step[0], step[1]), abs(wrap_angle(float(step[2]))), dt,
                           'searched', self._reset_window)
        return None

    def _search_reckoned(self, local: np.ndarray, prediction: np.ndarray, sigma: float,
                         stamp: Optional[float]) -> Optional[ScanMatch]:
        """
        Search a scan not matched while not localized within the odometry's error; or None.

        ``RECKONED_SEARCH``: the window from ``_reckoned``, the candidates of
        ``search_after_gap`` refined by ``match_scan`` against the map and the chords kept (where
        the saved map lacks walls they are all there is: review R, a laser blocked for 1.5 s
        there was never found against the map alone, 4-10 m off at the end), the best taken
        (relocalized) when it puts ``_gap_share`` of the scan on them and no place 0.5 m / 0.3
        rad from it comes within ``GAP_RIVAL`` of that share.
        """
        if self._reckoned is None or stamp is None or (
                self._searched is not None and 0 <= stamp - self._searched < RECKONED_SEARCH):
            return None
        self._searched = stamp
        shift, yaw = self._reckoned_reach()
        radius = min(max(shift, RELOCALIZE), GAP_REACH)
        turn = min(max(yaw, MATCH_REACH[1]), math.pi)
        best, rivals = _found_places(
            local, np.concatenate([self.mapper.segments, self._recent.chords()]), prediction,
            radius, turn, sigma)
        if best is None or best.share < self._gap_share() or rivals:
            return None
        return best._replace(relocalized=True)

    def _gap_share(self) -> float:
        """Return the share of a scan a pose found by a search must put on the map (GAP_SHARE)."""
        if not self._shares:
            return RELOCALIZE_SHARE
        return max(RELOCALIZE_SHARE, GAP_SHARE * _median(self._shares))

    def _trial_match(self, local: np.ndarray, prediction: np.ndarray) -> Optional[ScanMatch]:
        """
        Return a plain match of ``local`` from ``prediction`` (None: no map near it).

        Against the map and the recent chords within reach of the scan placed there, with the
        relocalization search and none of the prediction's terms (its covariance, the hold):
        to compare two predictions of one scan (``_odometry_jumped``).
        """
        sigma = self.mapper.sigma
        segs = self.mapper.segments if sigma is not None else np.zeros((0, 2, 2))
        near = np.concatenate([segs, self._recent.chords()])
        world = transform(local, prediction)
        reach = 0.5 + self.mapper.r + RELOCALIZE
        near = np.compress(in_box(near, world.min(axis=0) - reach, world.max(axis=0) + reach),
                           near, axis=0)
        if not len(near):
            return None
        return match_scan(local, prediction, near, sigma or MATCH_SIGMA, relocalize=RELOCALIZE)

    def _find_after_gap(self, local: np.ndarray, given: np.ndarray, prediction: np.ndarray,
                        segments: np.ndarray, sigma: float, window: tuple, base: np.ndarray,
                        stamp: float, estimate: np.ndarray = None,
                        reset: bool = False) -> tuple:
        """
        Find the scan after a gap (or a pose ``estimate``: its base pose) on the map; (pose, note).

        The scans after the gap are tracked against each other (``GapTrack``, in the frame of
        the first one). At each of its first ``GAP_KEYFRAMES`` keyframes, the best distinct
        poses of that first scan (``search_after_gap``, within ``window`` (m, rad) of the
        ``prediction``) for the keyframes' points are refined by ``match_scan``; the one putting
        most of them on the map is taken (``GAP_SHARE``, ``GAP_RIVAL``). Until then the session
        is lost (``_gap``): no scan is mapped; after them, or at once when the window is wider
        than ``GAP_REACH``, for good (until ``reset``). A warning when the session is lost
        and when it gives up. ``reset``: the odometry came back near its origin after a gap
        (``_reset_after_gap``; ``_localize`` warns that it is lost).
        """
        track = self._gap
        if track is None:
            since = self._motion[-1][0] if self._motion and estimate is None else stamp
            track = self._gap = GapTrack(since, stamp, prediction, window, estimate,
                                         self.options.chord_knots)
            # a gap in the scans themselves, or scans that kept coming and did not match
            track.paused = self._quiet is None or not 0 <= self._quiet <= self._gap_limit()
            if estimate is not None and self._tracked is not None:
                track.tracked = _compose(self._tracked, given)
            self._tracked = None
            track.reset = bool(reset)
            track.warned = int(track.reset)     # (lost: said by the odom_jump warning)
            if window[0] > GAP_REACH:
                track.why = (f'the robot may be anywhere within {window[0]:.1f} m, beyond the '
                             f'{GAP_REACH:g} m scan matching searches')
        odometry = self.options.pose_source != 'scan'
        if not track.final and track.add(stamp, local, sigma,       # a new keyframe:
                                         MATCH_DEGENERATE[self.options.pose_source],
                                         given if odometry else None):
            center = track.center
            best, rivals = _found_places(track.points(), segments, center, *track.window, sigma)
            need = self._gap_share()
            track.why = 'no pose puts the scans on the map'
            if best is not None:
                if track.estimate is None and (
                        math.hypot(*(best.pose[:2] - center[:2])) <= GAP_NEAR[0]
                        and abs(wrap_angle(best.pose[2] - center[2])) <= GAP_NEAR[1]):
                    need = RELOCALIZE_SHARE     # where a match from the prediction would be
                if rivals and track.estimate is not None and track.final:
                    # the last search near an estimate, else given up: its prior decides
                    best, rivals = _nearest_estimate([best] + rivals, center, track.window,
                                                     track.tracked)
                if best.share < need:
                    track.why = (f'the best pose puts {100 * best.share:.0f} % of the scans on '
                                 f'the map, under {100 * need:.0f} %')
                elif rivals:
                    apart = math.hypot(*(rivals[0].pose[:2] - best.pose[:2]))
                    track.why = f'places {apart:.1f} m apart explain the scans alike'
                else:
                    return self._found_after_gap(best, local, given, base)
        reason = ('not found after a gap' if track.estimate is None
                  else 'not found near the estimate')
        self._last_match = ScanMatch(prediction, _PRIOR, False, reason, 0, math.nan, 3)
        self.matches[reason] += 1
        if track.reset:
            cause, what = 'odom_reset', (
                f'the scans after the odometry came back near its origin (from '
                f'{track.since:.3f} s)')
            lost = f'has not found {what}'
        elif track.estimate is not None:
            x, y, yaw = track.estimate
            cause, what = 'pose_estimate', (
                f'the scans near the pose estimate ({x:.2f}, {y:.2f}, {yaw:.2f}; within '
                f'{track.window[0]:.2f} m and {track.window[1]:.2f} rad of the laser)')
            lost = f'has not found {what}'
        else:       # a gap in the scans (paused), or scans kept coming and none matched
            cause, what = 'scan_gap', (
                f'a gap of {track.first - track.since:.1f} s in the scans (from '
                f'{track.since:.3f} s)' if track.paused else
                f'{track.first - track.since:.1f} s of scans that did not match the map (from '
                f'{track.since:.3f} s; no gap in the scans)')
            lost, what = f'lost the track after {what}', f'the scans after {what}'
        if track.final and track.warned < 2:
            track.warned = 2
            return prediction, (f'{cause}_given_up', f'scan matching gave up finding {what}: '
                                f'{track.why}; no later scan is mapped (the map stays as it '
                                'was) until a pose estimate or a reset')
        if track.warned:
            return prediction, None
        track.warned = 1
        return prediction, (cause, f'scan matching {lost}: {track.why}; scans are not mapped '
                            'until they are found on the map again')

    def _found_after_gap(self, m: ScanMatch, local: np.ndarray, given: np.ndarray,
                         base: np.ndarray) -> tuple:
        """Take ``m``, the gap track's first scan on the map; return (this scan's pose, None)."""
        track, self._gap = self._gap, None
        motion = [(t, _compose(m.pose, p)) for t, p in track.motion]
        if len(motion) == 2:        # the tracked motion goes on (this scan is appended next)
            self._motion.clear()
            self._motion.append(motion[0])
        pose = motion[-1][1]
        self._last_match = m._replace(pose=pose, relocalized=True)
        self.matches['found after a gap' if track.estimate is None
                     else 'found near the estimate'] += 1
        self._found = True          # the gap, not the prediction, made the jump
        self._proposals.clear()
        self._set_anchor(base, motion[-1][0], pose)
        if track.reset:             # (the step across the reset is no pace)
            self._anchor_step = None
        self._shares.append(m.share)
        self._keyframe(local, pose)
        self._correction = _compose(pose, _inverse(given))
        return pose, None

    def _relocalize_share(self) -> float:
        """Return the share on the map below which a scan starts the relocalization search."""
        factor, scans, cap = RELOCALIZE_DROP
        if len(self._shares) < scans:
            return RELOCALIZE_SHARE
        return min(cap, max(RELOCALIZE_SHARE, factor * _median(self._shares)))

    @property
    def lost(self) -> bool:
        """
        Whether scan matching does not know where the scans are (no scan is mapped meanwhile).

        It refused the predicted pose, or it searches for the scans after a gap in them or
        near a pose estimate (or will, at the first scan that sees: ``_rearm``).
        """
        return bool(self._proposals) or self._gap is not None or self._rearm is not None

    def _confirm(self, local: np.ndarray, given: np.ndarray, m: ScanMatch, near: np.ndarray,
                 sigma: float, degenerate: float) -> ScanMatch:
        """
        Return ``m`` (refused as too large a correction), or the match its run confirms.

        A single scan that matches far from its prediction may be matched wrong; ``CONFIRM_JUMP``
        scans in a row that imply the same correction (within ``CONFIRM_AGREE``) are a jump of
        the odometry (a slip, a bump): the newest is matched again from its proposal and, if
        that match is taken, the result counts as relocalized.
        """
        self._proposals.append(_compose(m.proposal, _inverse(given)))
        if len(self._proposals) < CONFIRM_JUMP:
            return m
        c = np.array(self._proposals)
        d = c - c[-1]
        d[:, 2] = wrap_angle(d[:, 2])
        if (np.hypot(d[:, 0], d[:, 1]).max() > CONFIRM_AGREE[0]
                or np.abs(d[:, 2]).max() > CONFIRM_AGREE[1]):
            return m
        again = match_scan(local, m.proposal, near, sigma, degenerate=degenerate,
                           relocalize=RELOCALIZE)
        if not again.ok or again.share < RELOCALIZE_SHARE:     # the proposal explains little
            return m
        self._proposals.clear()
        return again._replace(relocalized=True)

    def _reckon(self, base: Optional[np.ndarray], matched: bool) -> None:
        """
        Carry the odometry's error since the last matched scan to this scan's base pose.

        ``_reckoned``: [covariance (odometry frame), the last base pose]; each step's error
        (``odometry_covariance``) is added and the heading's error so far moves the step's
        end sideways (an EKF's prediction: J P J^T + Q). Reset at a matched scan; None without
        base poses.
        """
        if base is None:
            self._reckoned = None
            return
        base = np.asarray(base, dtype=np.float64)
        if matched or self._reckoned is None:
            self._reckoned = [np.zeros((3, 3)), base.copy()]
            return
        cov, last = self._reckoned
        dx, dy = base[0] - last[0], base[1] - last[1]
        jac = np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])
        self._reckoned = [jac @ cov @ jac.T + odometry_covariance(_compose(_inverse(last), base)),
                          base.copy()]

    def _unmatched_spread(self, m: Optional[ScanMatch], base: Optional[np.ndarray]) -> np.ndarray:
        """
        Return what a scan not matched adds to its pose's covariance (m^2, rad^2; laser frame).

        The prediction's own prior (``_PRIOR``, 0.1 m and 0.05 rad) claimed a pose good to 10 cm
        while the session was lost and the error grew to metres (an audit). Added: the
        odometry's error over the motion since the last matched scan (``_reckon``: step by
        step along the path, each step's heading error moving the rest; until 2026-12-01 the
        straight step from there, so a loop back near that scan added little), a refused
        match's distance from the prediction (the scans may be either place), while searched
        for (after a gap or near a pose estimate) the search window's spread
        (``POSE_ESTIMATE_SIGMAS`` standard deviations), and once that search gave up
        ``GAP_REACH`` metres and half a turn as standard deviations: not localized (the
        odometry's error left out then: the pose is not known).
        """
        add = np.zeros((3, 3))
        given_up = self._gap is not None and self._gap.final
        if base is not None and self._reckoned is not None and not given_up:
            c, s = math.cos(self._correction[2]), math.sin(self._correction[2])
            turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])   # odom -> map
            add += turn @ self._reckoned[0] @ turn.T
        if m is not None and m.proposal is not None:
            dx, dy = np.asarray(m.proposal[:2], dtype=np.float64) - m.pose[:2]
            turn = wrap_angle(float(m.proposal[2]) - float(m.pose[2]))
            add += np.diag([dx * dx + dy * dy, dx * dx + dy * dy, turn * turn])
        if self._gap is not None or self._rearm is not None:
            sd = (np.asarray(self._rearm, dtype=np.float64) / POSE_ESTIMATE_SIGMAS
                  if self._gap is None else np.array([GAP_REACH, math.pi]) if self._gap.final
                  else np.asarray(self._gap.window, dtype=np.float64) / POSE_ESTIMATE_SIGMAS)
            add += np.diag([sd[0] ** 2, sd[0] ** 2, sd[1] ** 2])
        return add

    def _localize(self, stamp: float, given: np.ndarray, laser: np.ndarray,
                  before: np.ndarray, scan_frame: str = None, blind: bool = False) -> list:
        """
        Set ``localization`` after ``_match`` placed a scan; return jump warnings (cause, text).

        ``given``: the laser pose in the odometry frame, ``laser``: where the scan went in the
        fixed frame, ``before``: the correction before this scan. The base pose is the laser
        pose moved by the base's offset from the laser (its covariance carried along).
        ``blind``: a scan with nothing to match (``_blind``): not matched, ``_last_match`` (the
        scan before) left to the caller.
        """
        m = None if blind else self._last_match
        matched = m is not None and m.ok
        cov = np.array(m.covariance if m is not None else _PRIOR, dtype=np.float64)
        pose = np.asarray(laser, dtype=np.float64)
        base = self.poses.base_pose(stamp)
        self._reckon(base, matched)
        if not matched:
            cov = cov + self._unmatched_spread(m, base)
            if cov[2, 2] > math.pi ** 2:        # a heading beyond half a turn says no more
                d = np.array([1.0, 1.0, math.pi / math.sqrt(cov[2, 2])])
                cov = cov * np.outer(d, d)      # (D C D: still positive semi-definite)
        if base is not None:
            dx, dy, dyaw = _compose(_inverse(given), base)     # the base, laser frame
            c, s = math.cos(pose[2]), math.sin(pose[2])
            jac = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy],
                            [0.0, 0.0, 1.0]])
            pose, cov = _compose(pose, np.array([dx, dy, dyaw])), jac @ cov @ jac.T
        residual = float(m.residual) if matched else math.nan
        self.localization = Localization(
            float(stamp), pose, cov, np.array(self._correction, dtype=np.float64), matched,
            residual, self.poses.odom_frame, self.poses.base_frame if base is not None else None,
            scan_frame)
        notes = self._count_unmatched(stamp, matched)
        if matched:
            if (len(self._residuals) >= 10
                    and residual > JUMP_RESIDUAL * _median(self._residuals)):
                self.jumps['residual'] += 1
                ratio = residual / _median(self._residuals)
                notes.append(('residual_jump', f'scan matching residual jumped at {stamp:.3f} s: '
                              f'{100 * residual:.1f} cm, {ratio:.1f} x the running median (moved '
                              'objects, a new place, or a bad pose)'))
            self._residuals.append(residual)
            if self.options.pose_source != 'scan':
                notes += self._check_stamp_lag(stamp, given, laser, scan_frame)
        # The jump of map -> odom, seen at the laser: the match against the prediction.
        dx, dy, dyaw = _compose(_inverse(_compose(before, given)), laser)
        dyaw = wrap_angle(dyaw)
        found, self._found = self._found, False             # (warned at the run's first scan)
        jumped, self._odom_jump = self._odom_jump, None
        if jumped is not None:
            self.jumps['odometry'] += 1
            shift, turn, seconds, outcome, window = jumped
            if outcome == 'searched':
                notes.append(('odom_jump', f'the odometry came back near its origin at '
                              f'{stamp:.3f} s, {seconds:.1f} s after the last matched scan, '
                              f'{shift:.2f} m and {math.degrees(turn):.0f} deg from where it '
                              'had the robot then, and its prediction does not fit the scan '
                              '(its driver restarted?): ' + (
                                  'found on the map, map -> odom re-anchored' if found else
                                  f'searching the map within {window[0]:.1f} m and '
                                  f'{math.degrees(window[1]):.0f} deg of where its last pace led;'
                                  ' scans are not mapped until found')))
                return notes
            notes.append(('odom_jump', f'the odometry jumped at {stamp:.3f} s: {shift:.2f} m '
                          f'and {math.degrees(turn):.0f} deg off its pace in {seconds:.3f} s; '
                          + {
                              'anchored': 'the scan fits the last pace better (its driver '
                                          'restarted, a slip?): predicted so, map -> odom '
                                          're-anchored',
                              'followed': 'the scan fits the odometry at least as well (a '
                                          'recording played again, a robot carried?): '
                                          'followed',
                              'kept': 'the scan fits neither the last pace nor the odometry: '
                                      'the odometry kept'}[outcome]))
        elif (math.hypot(dx, dy) > JUMP_SHIFT or abs(dyaw) > JUMP_TURN) and not found:
            self.jumps['correction'] += 1
            notes.append(('correction_jump', f'map -> odom jumped at {stamp:.3f} s: the scan '
                          f'matched {100 * math.hypot(dx, dy):.0f} cm, {math.degrees(dyaw):.1f} '
                          'deg from the odometry prediction (wheel slip, a kidnapped robot, or '
                          'a wrong match)'))
        elif (m is not None and m.reason == 'correction too large'
              and len(self._proposals) == 1):         # the first scan of a run refused so
            self.jumps['correction'] += 1
            notes.append(('correction_jump', f'scan and odometry disagree at {stamp:.3f} s by '
                          'more than scan matching accepts: map -> odom kept (wheel slip, a '
                          'kidnapped robot?)'))
        return notes

    def _count_unmatched(self, stamp: float, matched: bool) -> list:
        """Count a scan not matched on a saved map (``UNMATCHED_STREAK``); return its warning."""
        if matched or not self._fixed() or self._gap is not None or self._rearm is not None:
            self._unmatched = None      # (searched for near an estimate, after a gap: lost)
            return []
        if self._unmatched is None or stamp < self._unmatched[0]:   # (a clock jump back)
            self._unmatched = [stamp, 0, False]
        run = self._unmatched
        run[1] += 1
        if run[2] or self.unmatched is None:
            return []
        run[2] = True
        sd = math.sqrt(max(self.localization.covariance[0, 0], self.localization.covariance[1, 1]))
        return [('not_localized', f'not localized since {run[0]:.3f} s: {run[1]} scans in a '
                 'row matched nothing of the saved map (the laser blocked, or the robot off the '
                 "map?); the poses are the odometry's until a search finds the scans on the "
                 f'map (now {sd:.2f} m std)')]

    @property
    def unmatched(self) -> Optional[tuple]:
        """
        Return (scans, seconds) not matched in a row on a saved map when not localized, else None.

        Not localized (``UNMATCHED_STREAK``): at least that many scans not matched in a row, the
        newest at least that many seconds after the first of them (at 10 Hz the 11th scan).
        """
        run = self._unmatched
        if run is None or self.localization is None:
            return None
        seconds = self.localization.stamp - run[0]
        if run[1] < UNMATCHED_STREAK[0] or seconds < UNMATCHED_STREAK[1]:
            return None
        return run[1], seconds

    def _check_stamp_lag(self, stamp: float, given: np.ndarray, laser: np.ndarray,
                         frame: Optional[str]) -> list:
        """
        Keep a matched scan's headings; every ``LAG_EVERY`` scans estimate the stamp lag.

        Returns a ``scan_clock`` warning when the scans are stamped ``LAG_WARN`` or more off
        the pose data's clock (once, and again when the estimate moves as much from it): a
        driver that stamps a scan when it is sent rather than at its first beam, or runs on
        another machine's clock. Such a lag poses every scan where the robot was at another
        time, which no match fully repairs over turns (``scan_time_offset`` shifts the stamps).
        """
        if self._lag_frame is None:
            self._lag_frame = frame
        elif frame != self._lag_frame:
            return []
        turns = self._turns
        if turns and stamp <= turns[-1][0]:
            if stamp >= turns[-1][0] - TIME_JUMP_BACK:
                return []                   # out of order: the rows stay in stamp order
            self._forget_lag()              # the clock went back: a new time line
        turns.append((float(stamp), float(given[2]), float(laser[2])))
        self._lag_new += 1
        if self._lag_new < LAG_EVERY:
            return []
        rows = np.array(turns)
        costs, pairs, self._lag_since = lag_costs(rows[:, 0], rows[:, 1], rows[:, 2],
                                                  self._lag_since)
        self._lag_new = 0
        while turns and turns[0][0] < self._lag_since - LAG_KEEP:
            turns.popleft()                 # (no later pair reads them)
        self._lag_costs = LAG_DECAY * self._lag_costs + costs
        self._lag_pairs = LAG_DECAY * self._lag_pairs + pairs
        if self._lag_pairs < LAG_PAIRS:
            return []
        est = self.stamp_lag = estimate_lag(self._lag_costs, self._lag_pairs)
        if not (abs(est.lag) >= LAG_WARN and est.rms * LAG_SURE <= est.rms_zero):
            return []                       # (nan: no pair counted)
        warned = self._lag_warned
        if warned is not None and (warned == est.lag or abs(est.lag - warned) < LAG_WARN):
            return []                       # (said; warned again once it moved as much)
        self._lag_warned = est.lag
        word = 'late' if est.lag > 0 else 'early'
        size = (f'{1000 * abs(est.lag):.0f} ms' if math.isfinite(est.lag) else
                f'{LAG_GRID[-1]:g} s or more')
        fix = self.options.scan_time_offset - est.lag
        advice = (f'set scan_time_offset to {fix:.3f}' if math.isfinite(fix) else
                  'find the offset and set scan_time_offset (this estimate reaches '
                  f'+-{LAG_GRID[-1]:g} s)')
        return [('scan_clock', f'the scans of {frame!r} look stamped {size} {word} against '
                 f'the pose data (at {stamp:.3f} s their matched turns agree '
                 f'{est.rms_zero / max(est.rms, 1e-6):.1f} x better with the odometry shifted '
                 'so): each '
                 'scan is posed where the robot was at another time, which smears the map in '
                 "turns. Fix the laser driver's stamps (the first beam's time, on the pose "
                 f"data's clock) or {advice}")]

    def _forget_lag(self) -> None:
        self._turns.clear()
        self._lag_costs[:] = 0.0
        self._lag_pairs = 0.0
        self._lag_new = 0
        self._lag_since = -math.inf

    def _run(self, max_updates: Optional[int], partial: bool, shed: bool = True) -> int:
        n = self.options.update_every_n_scans
        done = 0
        notes = []
        while max_updates is None or done < max_updates:
            with self._lock:
                if shed:
                    notes.extend(self._shed_late(n))
                if len(self._ready) < n and not (partial and self._ready):
                    break
                group = [self._ready.popleft() for _ in range(min(n, len(self._ready)))]
                gen = self._generation
            self._update(group, gen)
            done += 1
        self._emit(notes)
        return done

    def _shed_late(self, n: int) -> list:
        limit = self.options.max_latency
        if limit is None or self.clock is None:
            return []
        now = self.clock()
        notes = []
        while len(self._ready) > n and now - self._ready[0][4] > limit:
            self._ready.popleft()
            notes.append(self._dropped('too_late'))
        return notes

    def _dropped(self, cause: str) -> tuple:
        """Count and word one scan shed for load: ``cause`` 'queue_full' or 'too_late'."""
        opts = self.options
        return self._skip('dropped', cause, (
            f'the oldest queued scan: updates fall behind the scan rate (queue of '
            f'{opts.max_queue} scans)' if cause == 'queue_full' else
            f'a scan that waited more than {opts.max_latency:g} s for its update: updates are '
            'slower than the scans'))

    def _update(self, group: list, gen: int) -> bool:
        points = np.concatenate([g[1] for g in group])
        with self._map_lock:
            if gen != self._generation:     # a reset came in between: these scans are gone
                with self._lock:
                    self.cleared += len(group)
                return False
            ran = False
            t0 = time.perf_counter()
            if self.options.mapping:
                origin = (group[0][2] if len(group) == 1 else
                          np.repeat(np.array([g[2] for g in group]),
                                    [len(g[1]) for g in group], axis=0))
                try:
                    info = self.mapper.update(points, ordered=True, origin=origin)
                except ValueError as exc:           # e.g. a pose far beyond any real map
                    with self._lock:
                        note = self._skip('bad scan', 'bad_points', f'scans up to '
                                          f'{group[-1][0].stamp:.3f} s not mapped: {exc}',
                                          count=len(group))
                    if self._warn is not None:
                        self._warn(*note)
                    return False
                ran = info.skipped is None
                estimating = info.skipped == 'estimating noise'
            else:
                estimating = False
            seconds = time.perf_counter() - t0 + sum(g[3] for g in group)
            if self.grid is not None and self.options.mapping:
                t1 = time.perf_counter()
                origins = (group[0][2] if len(group) == 1 else
                           np.repeat(np.array([g[2] for g in group]),
                                     [len(g[1]) for g in group], axis=0))
                self.grid.add_beams(origins, points)
                self.grid_seconds.append(time.perf_counter() - t1)
            with self._lock:
                self.used += len(group)
                self.stamp = group[-1][0].stamp
                if self.options.keep_points:
                    self._points.append(points)
                    self._origins.append((np.array([g[2] for g in group], dtype=np.float64),
                                          [len(g[1]) for g in group]))
                if ran:
                    self.updates += 1
                if ran or not self.options.mapping:     # mapping off: convert and match
                    self.update_seconds.append(seconds)
                    self.convert_seconds.append(sum(g[3] for g in group))
                    if self.clock is not None:
                        self.latency_seconds.append(self.clock() - group[-1][4])
        if estimating and not self._estimating_noted and self._info is not None:
            self._estimating_noted = True
            self._info(f'estimating the noise scale from the first '
                       f'{self.mapper.config.noise_updates} updates; the map starts after them')
        return ran

    # -- readers -------------------------------------------------------------------------------
    @property
    def generation(self) -> int:
        """Return how many times the map was reset (a map value is current for one)."""
        return self._generation

    @property
    def fixed_frame(self) -> Optional[str]:
        """Return the map frame (known once the first scan is posed, unless given)."""
        return self.poses.fixed_frame

    @property
    def scan_frames(self) -> tuple:
        """Return the frames of the scans received (the newest ``MAX_SCAN_FRAMES``)."""
        with self._lock:
            return tuple(self._scan_stamps)

    @property
    def map_frame(self) -> str:
        """Return the frame of the map: a loaded map's own, else the fixed frame (or 'map')."""
        if self._loaded is not None:
            return self._loaded[0].frame_id
        return self.fixed_frame or 'map'

    def points(self) -> np.ndarray:
        """Return every mapped point, (N, 2) fixed frame (``keep_points`` only)."""
        with self._lock:
            return np.concatenate(self._points) if self._points else np.zeros((0, 2))

    def origins(self) -> np.ndarray:
        """
        Return the laser position of every mapped point, (N, 2), aligned with ``points()``.

        ``keep_points`` only: each point's beam runs from its origin to it (free-space metrics).
        """
        with self._lock:
            if not self._origins:
                return np.zeros((0, 2))
            return np.concatenate([np.repeat(o, c, axis=0) for o, c in self._origins])

    def scan_sizes(self) -> np.ndarray:
        """Return each mapped scan's number of points, (S,) int, in the order of ``points()``."""
        with self._lock:
            return np.array([n for _, c in self._origins for n in c], dtype=np.intp)

    def map_value(self, trajectory: Optional[bool] = None) -> MapValue:
        """
        Return the current map: segments, aligned support, polylines, frame, stamp, stats.

        ``trajectory``: with ``keep_points`` the scans' poses are included; True includes them
        live with scan matching too (the newest ``TRAJECTORY_ROWS``). A loaded map kept fixed
        (``load_map``, mapping off) is returned as loaded, in its own frame.
        """
        fixed = self._loaded is not None and not self.options.mapping
        with self._map_lock:
            geo = None if fixed else self.mapper.polylines()
            sigma, r = self.mapper.sigma, (self.mapper.r if self.mapper.sigma else None)
        if fixed:
            loaded = self._loaded[0]
            geo = MapGeometry(loaded.segments.copy(), loaded.support.copy(),
                              [p.copy() for p in loaded.polylines], list(loaded.closed))
            sigma, r = loaded.stats.get('sigma', sigma), loaded.stats.get('r', r)
        stats = self.stats()
        # (the window used: the configuration's -1 is resolved by the pose source)
        stats.update(segments=len(geo.segments), polylines=len(geo.polylines), sigma=sigma,
                     r=r, free_space_window=self.mapper.config.free_space_window)
        keep = self.options.keep_points or bool(trajectory and self.options.scan_matching)
        with self._lock:
            traj = np.array(self._trajectory, dtype=np.float64).reshape(-1, 4) if keep else None
        return MapValue(geo.segments, geo.support, geo.polylines, geo.closed, self.map_frame,
                        self.stamp, stats, traj)

    def occupancy(self, segments=None) -> Optional[GridMap]:
        """
        Return the planner map (``core.grid.GridMap``), or None when the session keeps no grid.

        Occupied cells from ``segments`` ((K, 2, 2); default: the current map's), free cells
        from the traced beams, unknown elsewhere; at ``options.grid_resolution``. The cells
        crossed by the segments as a map file stores them (``formats.mapjson.stored_segments``,
        0.1 mm) are occupied too, so the grid agrees with the published polylines and with the
        file's (a planner-map audit: 18 cells crossed by the office map's stored segments were
        free or unknown in its stored grid, the wall one row over).
        """
        if self.grid is None:
            return None
        if self._loaded is not None and not self.options.mapping and self._loaded[1] is not None:
            return self._loaded[1]
        if segments is None:
            with self._map_lock:
                segments = self.mapper.polylines().segments
        segments = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
        with self._map_lock:
            return self.grid.occupancy(np.concatenate([segments, stored_segments(segments)]))

    def stats(self) -> dict:
        """Counters, skips by cause, update-time (and live latency) percentiles in ms."""
        with self._lock:
            out = {'scans': self.received, 'scans_used': self.used, 'updates': self.updates,
                   'skipped': dict(sorted(self.skipped.items())),
                   'dropped': sum(v for k, v in self.skipped.items()
                                  if k.startswith('dropped:')),
                   # scans received = used + dropped + skipped + left out + cleared + queued
                   'scans_skipped': sum(v for k, v in self.skipped.items()
                                        if k.split(':')[0] in SCAN_SKIPS),
                   'scans_left_out': self.left_out, 'scans_cleared': self.cleared,
                   'scans_queued': self._queued()}
            if self.options.scan_matching:
                out['scan_matching'] = dict(sorted(self.matches.items()))
                out['match_jumps'] = dict(sorted(self.jumps.items()))
                out['match_held'] = self.held
            for key, values in (('update_ms', self.update_seconds),
                                ('latency_ms', self.latency_seconds)):
                if values:
                    out[key] = _percentiles(values)
        return out

    @property
    def loaded(self) -> Optional[MapValue]:
        """Return the saved map the session started from (``load_map``), or None."""
        return None if self._loaded is None else self._loaded[0]

    @property
    def used_since_reset(self) -> int:
        """Return the scans mapped since the session started or ``reset`` last cleared it."""
        return self.used - self._used_at_reset

    def reset(self) -> int:
        """
        Forget the map and every queued scan; return the number of segments dropped.

        The segments are counted as the map is published (``map_value``: the mapper's own
        before ``polylines()`` joins them were 25 for 24 on the office drive). A session
        started from a saved map (``load_map``) goes back to it; the robot stays where the scans
        were last matched when it was localized there (matched, not lost, no ``wrong_start``;
        with odometry or TF), else it goes back to the initial pose. (Until 2026-12-01 always
        the initial pose: a reset 14.5 m from the start put the robot there, and with mapping
        on the next scans were mapped into the saved map at the wrong place, an audit.)
        """
        dropped = len(self.map_value(trajectory=False).segments)
        with self._cv:
            keep = None if self._loaded is None else self._localized_correction()
            self._generation += 1
            self._used_at_reset = self.used
            self.cleared += self._queued()
            self.localization = None
            self._residuals.clear()
            self._forget_lag()
            self._waiting.clear()
            self._scan_stamps.clear()
            self._scan_steps.clear()
            self._leaps.clear()
            self._ready.clear()
            self._points.clear()
            self._trajectory.clear()
            self._first_base = None
            self.poses.forget_lasers()      # the next scan's laser, its mounts decide again
            self.pose_kept = keep is not None
            self._restart(None if self._loaded is None or keep is not None
                          else self._loaded[2])
            if keep is not None:                # predicted where the last match put it
                self._correction = keep
            self._origins.clear()
        with self._map_lock:
            self.mapper.reset()
            if self._loaded is not None:        # back to the loaded map and initial pose
                value = self._loaded[0]
                self.mapper.load(value.segments, value.support, self.mapper.sigma)
            if self.grid is not None:
                self.grid.reset()
                self.grid_seconds.clear()
            self.stamp = None
        self._seed_grid()
        return dropped
