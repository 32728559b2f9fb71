"""The controller and the arm in two processes: CRTK over Zenoh with ROS 2 (CDR) payloads.

``link.messages`` (key expressions as ``zenoh-bridge-ros2dds`` maps ROS 2 topics, the messages
and their CDR coding through ``rosbags``), ``link.server`` (``endocam robot serve``: the
simulated arm and world as a robot process), ``link.client`` (``endocam control``: the
Actuator-shaped client and the episode run against it). Needs the ``robot`` extra.
"""
