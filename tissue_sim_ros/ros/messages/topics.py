"""The node's topics: names, types and QoS profiles, in one place.

Topics (relative names; remap with ``--ros-args -r``), all reliable:

==================== ================================ ===================================
``needle/pose``      geometry_msgs/msg/PoseStamped    in: pose of the needle base frame in
                                                      ``frame_id`` (needle axis = its +z)
``needle/wrench``    geometry_msgs/msg/WrenchStamped  out, every tick: the wrench the tissue
                                                      exerts on the needle [N, N m], about
                                                      the needle base origin, expressed in
                                                      ``wrench.frame_id``
``needle/shape``     nav_msgs/msg/Path                out, every tick: the needle's centreline
                                                      from the base to the tip in ``frame_id``
                                                      (a flexible needle's rod nodes; the last
                                                      pose is the tip's frame;
                                                      :mod:`~tissue_sim_ros.ros.messages.needle_shape`)
``tissue/nodes``     sensor_msgs/msg/PointCloud2      out, every tick while it has a
                                                      subscriber: every vertex, fields
                                                      x y z (deformed) ux uy uz (displacement)
``tissue/surface``   shape_msgs/msg/Mesh              out, transient local: rest vertices (same
                                                      order as the cloud) and the surface
                                                      triangles; at start and after every
                                                      topology change
``tissue/marker``    visualization_msgs/msg/Marker    out, ``marker_rate_hz`` (from a tick): surface,
                                                      TRIANGLE_LIST, decimated for RViz
``tissue/targets``   geometry_msgs/msg/PoseArray      out, every tick: the scene's targets where
                                                      the tissue carried them (scene order)
``plan/candidate``   nav_msgs/msg/Path                in: a candidate path of the needle base
                                                      (stamped poses in ``frame_id``, the first
                                                      where the needle is now)
``plan/prediction``  trajectory_msgs/msg/JointTrajectory out: the answer to each candidate, in
                                                      order, its stamp the request's
                                                      (:mod:`~tissue_sim_ros.ros.predictions`)
``/diagnostics``     diagnostic_msgs/DiagnosticArray  out, ``diagnostics_rate_hz``
``/tf``              tf2_msgs/msg/TFMessage           out, every tick: the needle base frame(s) and
                                                      the targets' frames in ``frame_id``; in: the
                                                      robot's frames (:mod:`~tissue_sim_ros.ros.tf_in`)
``/tf_static``       tf2_msgs/msg/TFMessage           out, transient local: ``frame_id`` in
                                                      ``registration.parent_frame_id``, the needle
                                                      tip frame(s); in: the robot's static frames
``~/ready``          std_msgs/msg/Bool                out, transient local: false while starting,
                                                      true once the node ticks
==================== ================================ ===================================

The action ``~/predict_path`` (tissue_sim_msgs/action/PredictPath) answers a path as
``plan/candidate`` does, with feedback and a typed result (:mod:`~tissue_sim_ros.ros.prediction_action`).

A scene with several needles (scene key ``needles``) has ``needle/<name>/pose``,
``needle/<name>/wrench`` and ``needle/<name>/shape`` per needle instead of ``needle/pose``,
``needle/wrench`` and ``needle/shape``
(:func:`needle_topics`).

The surface is transient local so that a late subscriber gets the mesh it needs to read the cloud.
"""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ['qos', 'WRENCH_QOS', 'NODES_QOS', 'SURFACE_QOS', 'MARKER_QOS', 'DIAGNOSTICS_QOS',
           'SERVICE_EVENT_QOS', 'PLAN_QOS', 'TF_QOS', 'TF_STATIC_QOS', 'READY_QOS', 'pose_qos',
           'NODE_TOPIC_TYPES', 'needle_topics']


def qos(depth: int, transient_local: bool = False,
         reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient_local else DurabilityPolicy.VOLATILE)


WRENCH_QOS = qos(10)
NODES_QOS = qos(2)
SURFACE_QOS = qos(1, transient_local=True)
MARKER_QOS = qos(1)
DIAGNOSTICS_QOS = qos(10)
SERVICE_EVENT_QOS = qos(10)
#: plan/candidate and plan/prediction: a burst of requests and their answers all kept
PLAN_QOS = qos(100)
#: /tf and /tf_static as tf2_ros's broadcasters and listeners use them
TF_QOS = qos(100)
TF_STATIC_QOS = qos(1, transient_local=True)
#: ~/ready: latched, so a supervisor that comes late reads the state
READY_QOS = qos(1, transient_local=True)


def pose_qos(reliability: str) -> QoSProfile:
    """needle/pose: 100 deep, enough for a 1 kHz flood during a tick; 'reliable' or
    'best_effort' (which also accepts best-effort publishers)."""
    return qos(100, reliability=ReliabilityPolicy.RELIABLE if reliability == 'reliable'
               else ReliabilityPolicy.BEST_EFFORT)


#: The node's published topics (relative names) and their ROS types, as the log declares them.
NODE_TOPIC_TYPES = {
    'needle/wrench': 'geometry_msgs/msg/WrenchStamped',
    'needle/shape': 'nav_msgs/msg/Path',
    'tissue/nodes': 'sensor_msgs/msg/PointCloud2',
    'tissue/surface': 'shape_msgs/msg/Mesh',
    'tissue/marker': 'visualization_msgs/msg/Marker',
    'tissue/targets': 'geometry_msgs/msg/PoseArray',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    'needle/pose': 'geometry_msgs/msg/PoseStamped',
    'plan/candidate': 'nav_msgs/msg/Path',
    'plan/prediction': 'trajectory_msgs/msg/JointTrajectory',
    '/tf': 'tf2_msgs/msg/TFMessage',
    '/tf_static': 'tf2_msgs/msg/TFMessage',
    '~/ready': 'std_msgs/msg/Bool',
}


def needle_topics(names) -> list[tuple[str, str]]:
    """(pose topic, wrench topic) per needle: needle/pose and needle/wrench for a scene with one
    needle, needle/<name>/pose and needle/<name>/wrench for each of several."""
    if len(names) == 1:
        return [('needle/pose', 'needle/wrench')]
    return [(f'needle/{name}/pose', f'needle/{name}/wrench') for name in names]
