"""
The bag layer: rosbag2 bags in MCAP, written and read through the ``mcap`` library.

``ros_types`` maps ROS message types to their classes, full definitions and type hashes,
and QoS profiles to and from rosbag2's YAML; ``writer`` keeps the rosbag2 layout
(``metadata.yaml``, QoS and type-hash channel metadata), crash safety, file splitting and
``reindex``; ``reader`` opens bags, damaged ones too; ``recorder`` turns the learner's
episodes into messages.
"""
