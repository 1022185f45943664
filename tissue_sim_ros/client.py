"""``tissue_sim_ros.client``: what a planner imports to ask the running node for predictions.

The client of the node's ``~/predict_path`` action (:mod:`tissue_sim_ros.ros.clients.predict_client`):
``PredictionClient().predict(path)`` returns the prediction as numpy arrays by column, and as a
pandas DataFrame when pandas is installed. It needs rclpy and the tissue_sim_msgs interfaces (the
set-up builds them). It sits with the command line, at the top of the layers: a user's entry point.
"""
from tissue_sim_ros.ros.clients.predict_client import PathPrediction, PredictionClient, PredictionRefused

__all__ = ['PathPrediction', 'PredictionClient', 'PredictionRefused']
