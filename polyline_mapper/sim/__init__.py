"""A physically simulated 2D laser in worlds of walls and arcs, for tests, benchmarks and demos."""

from .laser import LaserSpec, simulate_drive, SimulatedDrive
from .world import Arc, corridor_loop, hall_with_arc, office_floor, path_poses, World

__all__ = ['Arc', 'corridor_loop', 'hall_with_arc', 'LaserSpec', 'office_floor', 'path_poses',
           'simulate_drive', 'SimulatedDrive', 'World']
