"""The virtual Kinect v2: scenes, error model, renderer and dataset writers; a family of random sensors.

>>> from tofmetry.simulate import VirtualKinect, ErrorModel, scenes, datasets
>>> vk = VirtualKinect(errors=ErrorModel().without("noise"), seed=0)
>>> frames = vk.capture(scenes.wall(distance_m=1.0), n_frames=5)       # doctest: +SKIP
>>> from tofmetry.simulate import random_sensor, wall_station_means
>>> stations = wall_station_means(random_sensor(7), [1000, 2000], n_frames=10)  # doctest: +SKIP
"""

from tofmetry.simulate import scenes
from tofmetry.simulate.camera import Frame, Frames, VirtualKinect
from tofmetry.simulate.color import ColourCamera, ColourRendering, default_texture, occluder_scene, render_colour, true_point_colours
from tofmetry.simulate.errors import TERMS, ErrorModel
from tofmetry.simulate.family import SensorDraw, default_sensor, random_sensor, station_tilts
from tofmetry.simulate.meshes import balustrade_mesh
from tofmetry.simulate.poses import look_at, orbit_poses
from tofmetry.simulate.render import Rendering, render
from tofmetry.simulate.surfaces import Scene
from tofmetry.simulate.walls import StationMean, wall_station_means

from tofmetry.simulate import datasets  # noqa: E402  (imports the above)

__all__ = ["VirtualKinect", "ErrorModel", "Frames", "Frame", "Rendering", "render", "TERMS", "Scene", "scenes",
           "datasets", "balustrade_mesh", "look_at", "orbit_poses", "SensorDraw", "random_sensor", "default_sensor",
           "station_tilts", "StationMean", "wall_station_means",
           "ColourCamera", "ColourRendering", "default_texture", "occluder_scene", "render_colour", "true_point_colours"]
