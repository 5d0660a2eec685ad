"""A physically simulated 2D laser in worlds of walls and arcs, for tests, benchmarks and demos."""

from .laser import LaserSpec, simulate_drive, SimulatedDrive
from .world import Arc, corridor_loop, hall_with_arc, office_dynamic, office_floor, path_poses
from .world import Removed, Walker, World

__all__ = ['Arc', 'corridor_loop', 'hall_with_arc', 'LaserSpec', 'office_dynamic',
           'office_floor', 'path_poses', 'Removed', 'simulate_drive', 'SimulatedDrive',
           'Walker', 'World']
