"""The node's services, each recorded (request and response) in its log:

=========================== =============================== ================================================
``~/reset``                 std_srvs/srv/Trigger            tissue at rest, needle at its start pose
``~/pause``                 std_srvs/srv/SetBool            freeze (true) or resume (false) the simulation
``~/set_tissue_pose``       tissue_sim_msgs/srv/SetTissuePose  the tissue's registration in the robot's frame:
                                                            republished on /tf_static (:mod:`.registration`)
``~/register_needle``       std_srvs/srv/Trigger            the needle starts where the robot holds it now
                                                            (its newest pose), while it is out of the tissue
=========================== =============================== ================================================

A service runs on the node's executor and reaches the engine through a job on the engine's thread
(``EngineLoop.call``): one thread only ever touches the engine's state.
"""

from __future__ import annotations

import numpy as np

from tissue_sim_ros.errors import InputError

__all__ = ['NodeServices', 'SERVICE_TYPES']

#: every service (relative to the node) and its ROS type, as the log records its events
SERVICE_TYPES = {
    '~/reset': 'std_srvs/srv/Trigger',
    '~/pause': 'std_srvs/srv/SetBool',
    '~/set_tissue_pose': 'tissue_sim_msgs/srv/SetTissuePose',
    '~/register_needle': 'std_srvs/srv/Trigger',
}


class NodeServices:
    """The services of ``node`` (a TissueSimNode): created here, answered here."""

    def __init__(self, node):
        from std_srvs.srv import SetBool, Trigger
        from tissue_sim_msgs.srv import SetTissuePose

        self.node = node
        self.types = {
            '~/reset': Trigger,
            '~/pause': SetBool,
            '~/set_tissue_pose': SetTissuePose,
            '~/register_needle': Trigger,
        }
        handlers = {
            '~/reset': self._reset,
            '~/pause': self._pause,
            '~/set_tissue_pose': self._set_tissue_pose,
            '~/register_needle': self._register_needle,
        }
        self.services = {
            name: node.create_service(self.types[name], name, self._recorded(name, handler))
            for name, handler in handlers.items()
        }

    def _recorded(self, name, handler):
        def answer(request, response):
            response = handler(request, response)
            self.node._record_call(self.services[name], self.types[name], request, response)
            return response

        return answer

    def _reset(self, request, response):
        node = self.node
        node.engine.reset()
        node.get_logger().info('~/reset: tissue at rest, needle at its start pose')
        response.success = True
        response.message = (
            f'reset: simulated time {node.scene.time:g} s, needle at '
            f'{[round(float(x), 6) for x in node.scene.needle_pose[0]]} m; poses '
            f'farther than input.max_jump_m from it are refused'
        )
        return response

    def _pause(self, request, response):
        engine = self.node.engine
        was = engine.paused

        def set_paused():
            engine.paused = bool(request.data)

        engine.call(set_paused)
        response.success = True
        response.message = (
            f'{"paused" if engine.paused else "running"} at simulated time '
            f'{self.node.scene.time:.6g} s' + ('' if was != engine.paused else ' (unchanged)')
        )
        self.node.get_logger().info(f'~/pause: {response.message}')
        return response

    def _set_tissue_pose(self, request, response):
        node = self.node
        p, o = request.pose.pose.position, request.pose.pose.orientation
        try:
            response.message = node.registration.set_tissue_pose(
                request.pose.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w)
            )
            response.success = True
            node.publish_static_transforms()
            node.get_logger().info(f'~/set_tissue_pose: {response.message}')
        except InputError as exc:
            response.success, response.message = False, f'refused: {exc}'
            node.get_logger().warning(f'~/set_tissue_pose: {response.message}')
        return response

    def _register_needle(self, request, response):
        node = self.node
        try:
            position, orientation = node.engine.place()
            response.success = True
            response.message = (
                f'the needle starts at {np.round(position, 6).tolist()} m, orientation '
                f'{np.round(orientation, 6).tolist()} in {node.config.frame_id!r} (also after ~/reset)'
            )
            node.get_logger().info(f'~/register_needle: {response.message}')
        except InputError as exc:
            response.success, response.message = False, f'refused: {exc}'
            node.get_logger().warning(f'~/register_needle: {response.message}')
        return response
