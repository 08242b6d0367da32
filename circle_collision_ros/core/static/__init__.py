"""Static geometry: the first contact of moving circles with maps, polygons and walls (2-D).

``StaticWorld.build`` turns named obstacles (``Polygon``, ``Segments``, ``OccupancyMap``)
into edges and corner points; ``StaticIndex.build`` indexes them once; ``time_to_static``
answers a batch of bodies against the index.  Below them: the certified edge kernel
(``edge``), its exact decision (``edge_exact``) and the occupancy-grid boundary
(``occupancy``).  Exactness and methods: docs/static.md.
"""
from circle_collision_ros.core.static.index import StaticIndex
from circle_collision_ros.core.static.occupancy import GridFrame, occupied_cells
from circle_collision_ros.core.static.query import StaticContacts, time_to_static
from circle_collision_ros.core.static.world import (
    OccupancyMap,
    Polygon,
    Segments,
    StaticWorld,
)

__all__ = ["StaticWorld", "StaticIndex", "Polygon", "Segments", "OccupancyMap", "GridFrame",
           "occupied_cells", "StaticContacts", "time_to_static"]
