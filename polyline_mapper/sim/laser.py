"""
A 2D laser scanner, simulated by ray casting, with the failure modes real ones have.

Readings follow the LaserScan / REP 117 conventions: a beam that hits nothing within
``range_max`` reads +inf, a dropout (no echo from a dark or specular surface) reads NaN, and a
hit gets Gaussian range noise. Everything random comes from one seeded generator.
"""

from dataclasses import dataclass

import numpy as np

from .world import path_poses, World
from ..scan import scan_to_points, valid_ranges


@dataclass
class LaserSpec:
    """Scanner geometry and noise; angles in radians, lengths in metres."""

    beams: int = 541
    fov: float = np.deg2rad(270.0)
    range_min: float = 0.05
    range_max: float = 12.0
    noise: float = 0.01
    """Standard deviation of the range noise (m)."""
    noise_share: float = 0.0
    """Standard deviation of a second range noise, as a share of the range (0.01: 1 cm at 1 m;
    cheap lidars, RPLidar-class). Drawn after the dropouts, so a drive with it has the same
    dropouts and constant noise as the drive without it (same seed)."""
    dropout: float = 0.01
    """Probability that a beam returns NaN."""

    def __post_init__(self):
        """Reject impossible geometry."""
        if int(self.beams) != self.beams or self.beams < 1:
            raise ValueError(f'beams must be an integer >= 1, got {self.beams!r}')
        if not 0 < self.fov <= 2 * np.pi:
            raise ValueError(f'fov must be in (0, 2 pi], got {self.fov!r}')
        if not 0 <= self.range_min < self.range_max:
            raise ValueError('need 0 <= range_min < range_max')
        if (not (np.isfinite(self.noise) and self.noise >= 0) or not 0 <= self.dropout < 1
                or not 0 <= self.noise_share < 1):
            raise ValueError('need noise >= 0, 0 <= noise_share < 1 and 0 <= dropout < 1')

    @property
    def angle_min(self) -> float:
        """First beam angle (rad), the scan is centred on the x axis."""
        return -0.5 * self.fov

    @property
    def angle_increment(self) -> float:
        """Angle between beams (rad)."""
        # np.isclose(fov, 2 pi)'s test (rtol 1e-5, atol 1e-8) in Python floats: a NumPy call
        # cost more than the rest of a simulated scan's angles.
        full = abs(self.fov - 2 * np.pi) <= 1e-8 + 1e-5 * abs(2 * np.pi)
        return self.fov / (self.beams if full else max(self.beams - 1, 1))

    def angles(self) -> np.ndarray:
        """Compute each beam's angle in the laser frame, radians, shape (beams,)."""
        return self.angle_min + self.angle_increment * np.arange(self.beams)


def simulate_scan(world: World, pose, spec: LaserSpec, rng, t: float = None) -> tuple:
    """
    One scan from ``pose`` = (x, y, yaw), at time ``t`` (s) for a world with dynamic objects.

    ``pose`` may also be (beams, 3): each beam cast from its own pose (a moving sensor).

    Returns
    -------
    ranges : (beams,) metres with +inf for no return and NaN for dropouts.
    hit : (beams,) index of the object hit (see ``World.cast``), -1 for none.

    """
    pose = np.asarray(pose, dtype=np.float64)
    ang = spec.angles() + pose[..., 2]
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    true, hit = world.cast(pose[..., :2], d, t)
    ranges = true + rng.normal(0.0, spec.noise, size=true.shape)
    drop = rng.random(true.shape) < spec.dropout
    if spec.noise_share:
        seen = np.isfinite(true)
        ranges[seen] += rng.normal(0.0, spec.noise_share, size=int(seen.sum())) * true[seen]
    ranges[(true >= spec.range_max) | ~np.isfinite(true)] = np.inf
    hit = np.where(np.isfinite(ranges), hit, -1)
    ranges[ranges < spec.range_min] = -np.inf
    ranges[drop] = np.nan
    hit[drop] = -1
    return ranges, hit


@dataclass
class SimulatedDrive:
    """
    Scans along a path: poses (P, 3), ranges (P, B), hit ids (P, B), and the laser.

    ``poses`` are the laser poses at the scans' stamps. With a moving sensor
    (``time_increment`` > 0) beam i of a scan is taken ``i * time_increment`` s after its
    stamp, from the pose interpolated at that time (``beam_poses``), as a spinning lidar does.
    """

    world: World
    spec: LaserSpec
    poses: np.ndarray
    ranges: np.ndarray
    hits: np.ndarray
    stamps: np.ndarray
    time_increment: float = 0.0
    """Seconds between beams (0: every beam at the scan's stamp)."""
    scan_time: float = 0.0
    """Seconds between scans, as LaserScan.scan_time (0 for a sensor taken as not moving)."""

    def beam_poses(self, index: int) -> np.ndarray:
        """Return the laser pose of each beam of scan ``index``, (B, 3), at the beam's time."""
        return _interpolate(self.poses, self.stamps, self.stamps[index]
                            + self.time_increment * np.arange(self.spec.beams))

    def points(self, with_hits: bool = False):
        """All valid readings registered with the true poses, (N, 2) metres (and hit ids)."""
        angles = self.spec.angles()
        if self.time_increment > 0:
            pts = [_beam_points(r, angles, self.beam_poses(k), self.spec)
                   for k, r in enumerate(self.ranges)]
        else:
            pts = [scan_to_points(r, angles, p, self.spec.range_min, self.spec.range_max)
                   for r, p in zip(self.ranges, self.poses)]
        pts = np.concatenate(pts) if pts else np.zeros((0, 2))
        if not with_hits:
            return pts
        hits = np.concatenate([h[valid_ranges(r, self.spec.range_min, self.spec.range_max)]
                               for r, h in zip(self.ranges, self.hits)])
        return pts, hits

    def origins(self, per_beam: bool = True) -> np.ndarray:
        """
        Return the laser position of each point of ``points()``, (N, 2) metres.

        With a moving sensor (``time_increment`` > 0) each beam's own, unless ``per_beam`` is
        False: then its scan's pose, as for a fixed sensor. ``smemsf.fit`` takes a run of
        equal rows as one look (one scan), so give it ``origins(per_beam=False)``.
        """
        ok = [valid_ranges(r, self.spec.range_min, self.spec.range_max) for r in self.ranges]
        if per_beam and self.time_increment > 0:
            return (np.concatenate([self.beam_poses(k)[m, :2] for k, m in enumerate(ok)])
                    if ok else np.zeros((0, 2)))
        n = [np.count_nonzero(m) for m in ok]
        return np.repeat(self.poses[:, :2], n, axis=0) if n else np.zeros((0, 2))


def _interpolate(poses: np.ndarray, stamps: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Poses (P, 3) at ``stamps`` (P,) linearly interpolated at ``times``, held at the ends."""
    yaw = np.unwrap(poses[:, 2])
    return np.column_stack([np.interp(times, stamps, poses[:, 0]),
                            np.interp(times, stamps, poses[:, 1]),
                            np.interp(times, stamps, yaw)])


def _beam_points(ranges, angles, poses, spec: LaserSpec) -> np.ndarray:
    """Points of one scan whose beams are taken from their own poses (B, 3), (M, 2) metres."""
    ok = valid_ranges(ranges, spec.range_min, spec.range_max)
    r = np.asarray(ranges, dtype=np.float64)[ok]
    p = poses[ok]
    a = angles[ok] + p[:, 2]
    return np.stack([p[:, 0] + r * np.cos(a), p[:, 1] + r * np.sin(a)], axis=1)


def simulate_drive(world: World, spec: LaserSpec = None, step: float = 0.25, rate: float = 10.0,
                   rng=0, waypoints=None, turn: float = None,
                   scan_time: float = 0.0) -> SimulatedDrive:
    """
    Drive along ``waypoints`` (default: the world's path), one scan every ``step`` metres.

    ``rate`` (Hz) sets the time stamps, and with them what the world's dynamic objects (people
    walking, a door that opens, a box carried away) do while the scans are taken: scan i sees the
    world at time i / rate. ``rng`` is a seed or a numpy Generator. ``turn`` (rad): turn in
    place at the waypoints, at most this much per scan (``path_poses``).

    ``scan_time`` (s) > 0: a moving sensor, a lidar spinning once in that time: beam i is taken
    ``i * time_increment`` s after the scan's stamp (``time_increment`` = ``scan_time`` x
    angle increment / 2 pi, float32 as in a LaserScan), cast from the pose interpolated
    (linearly, between the scans' poses) at that time. 0: every beam from the scan's pose.
    """
    spec = spec or LaserSpec()
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError(f'rate must be a number > 0 (Hz), got {rate!r}')
    if not (np.isfinite(scan_time) and scan_time >= 0):
        raise ValueError(f'scan_time must be a finite number >= 0 (s), got {scan_time!r}')
    rng = np.random.default_rng(rng)
    poses = path_poses(world.path if waypoints is None else waypoints, step, turn)
    stamps = np.arange(len(poses)) / rate
    if scan_time > 0:
        dt = float(np.float32(scan_time * spec.angle_increment / (2 * np.pi)))
        beams = dt * np.arange(spec.beams)
        scans = [simulate_scan(world, _interpolate(poses, stamps, t + beams), spec, rng, t)
                 for t in stamps]
    else:
        dt = 0.0
        scans = [simulate_scan(world, p, spec, rng, t) for p, t in zip(poses, stamps)]
    ranges = np.array([s[0] for s in scans])
    hits = np.array([s[1] for s in scans])
    return SimulatedDrive(world, spec, poses, ranges, hits, stamps, dt,
                          float(np.float32(scan_time)))
