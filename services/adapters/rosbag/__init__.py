"""ROS bags in: the RGB-D images of a ROS 1 or ROS 2 bag (read with rosbags, no ROS install)
as RgbdFrames on ``sensors/rgbd/<camera>`` (``avs replay-bag``).

``convert`` holds the pure message conversions (image buffers, depth to metres, CameraInfo,
transforms), ``tf`` a small interpolating tf tree, ``bag`` the reading and pairing, and
``publish`` the thin Zenoh side.
"""
