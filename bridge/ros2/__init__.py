"""ROS 2 topics over rmw_zenoh: key and token names, the attachment, CDR through ``rosbags``.

Modules: :mod:`~bridge.ros2.names` (keys, liveliness tokens, QoS text),
:mod:`~bridge.ros2.attachment`, :mod:`~bridge.ros2.messages` (type store, hashes, CDR),
:mod:`~bridge.mission.ros2` (the mission's ``ros2`` block), :mod:`~bridge.ros2.element` (a compiled
element) and :mod:`~bridge.runtime.ros2_graph` (the Zenoh adapter: publishers, attachments, tokens).
Nothing is imported here, so missions without ROS 2 never load ``rosbags``.
"""
