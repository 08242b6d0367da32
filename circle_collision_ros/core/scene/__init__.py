"""Scene prediction: every pair of a set of bodies, all at once or incrementally.

``predict_all_pairs`` answers a whole scene of states (broad phase, then the
narrow phase on the candidates); ``Scene`` keeps the bodies of a state stream
and their pair predictions, re-evaluating only what each update changes.
"""
from circle_collision_ros.core.scene.all_pairs import PairPredictions, predict_all_pairs
from circle_collision_ros.core.scene.results import (DeferredInputs, MergeResult, SceneContacts,
                                                     SceneSnapshot, SceneUncertainty)
from circle_collision_ros.core.scene.scene import Scene
from circle_collision_ros.core.scene.uncertain import complete_uncertainty

__all__ = ["PairPredictions", "predict_all_pairs", "Scene", "SceneContacts", "SceneSnapshot",
           "SceneUncertainty", "DeferredInputs", "MergeResult", "complete_uncertainty"]
