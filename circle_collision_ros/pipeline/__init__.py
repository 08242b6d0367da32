"""Received circle states to predictions, without a ROS graph (shared by node, service and replay).

    bytes -> state_codec / odometry -> StateBatch -> state_validation -> predictor
          -> ScenePrediction (prediction_messages) -> prediction_codec -> bytes

Message codecs, each one message's encoder and decoder together, on the CDR
primitives of ``cdr``: ``state_codec`` (CircleState, CircleStateArray),
``prediction_codec`` (CollisionPredictionArray), ``odometry`` (nav_msgs/Odometry
in). Importing this package loads numba, the message packages and ``core``,
never rclpy.
"""
from circle_collision_ros.pipeline.cdr import CdrError, decode_string
from circle_collision_ros.pipeline.odometry import (ODOMETRY_TYPE, OdometryError, OdometrySource,
                                                    decode_odometry, odometry_batch,
                                                    odometry_sources)
from circle_collision_ros.pipeline.prediction_codec import (PairPrediction, PredictionArray,
                                                            decode_prediction_array,
                                                            encode_contact_rows,
                                                            encode_prediction_array,
                                                            peek_prediction_array)
from circle_collision_ros.pipeline.prediction_messages import (PredictionColumns, PredictionRow,
                                                               ScenePrediction)
from circle_collision_ros.pipeline.predictor import (RUNTIME_FIELDS, CollisionPredictor,
                                                     HorizonLimits, IntakeReport, PredictionStats,
                                                     PredictorConfig, predict_once)
from circle_collision_ros.pipeline.state_batch import StateBatch
from circle_collision_ros.pipeline.state_codec import (COVARIANCE_SIZE, StateDecoder, decode_states,
                                                       encode_state, encode_state_array)
from circle_collision_ros.pipeline.state_groups import GroupOutcome, ingest_single_states
from circle_collision_ros.pipeline.state_validation import BatchCheck, Rejection, check_batch

__all__ = [
    # the predictor
    "CollisionPredictor",
    "PredictorConfig",
    "IntakeReport",
    "PredictionStats",
    "HorizonLimits",
    "RUNTIME_FIELDS",
    "predict_once",
    # its input and output forms
    "StateBatch",
    "ScenePrediction",
    "PredictionColumns",
    "PredictionRow",
    "check_batch",
    "BatchCheck",
    "Rejection",
    "ingest_single_states",
    "GroupOutcome",
    # codecs
    "CdrError",
    "decode_string",
    "COVARIANCE_SIZE",
    "decode_states",
    "StateDecoder",
    "encode_state",
    "encode_state_array",
    "PairPrediction",
    "PredictionArray",
    "decode_prediction_array",
    "peek_prediction_array",
    "encode_prediction_array",
    "encode_contact_rows",
    "ODOMETRY_TYPE",
    "OdometryError",
    "OdometrySource",
    "decode_odometry",
    "odometry_batch",
    "odometry_sources",
]
