"""Broad phase: cull body pairs that provably cannot touch within a time window.

Swept bounds of each body's arc (bounds.py), a relative-motion filter on the
surviving pairs (relative.py), and two pair generators: sort-and-sweep
(sweep.py, the default of ``candidate_pairs``) and a uniform grid (grid.py);
the hashed grid (grid.cell_keys) answers one body's candidates for the
incremental scene; ego.py lists only the pairs with an ego body (ego-centred scenes).
"""
from circle_collision_ros.core.broad.bounds import propagate, swept_bound_row, swept_bounds
from circle_collision_ros.core.broad.ego import ego_box_keys, ego_candidate_pairs
from circle_collision_ros.core.broad.grid import MAX_CELLS_PER_BODY, cell_keys, choose_cell_size
from circle_collision_ros.core.broad.relative import gather_states, rel_keep, relative_filter
from circle_collision_ros.core.broad.sweep import candidate_pairs

__all__ = ["candidate_pairs", "propagate", "swept_bounds", "swept_bound_row", "relative_filter",
           "rel_keep", "gather_states", "cell_keys", "choose_cell_size", "MAX_CELLS_PER_BODY",
           "ego_box_keys", "ego_candidate_pairs"]
