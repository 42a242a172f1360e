"""RealSense adapter: a D400-series camera (or a recording of one) publishing aligned RGB-D
frames and the IMU on the sim's keys. pyrealsense2 is optional (``pip install 'avs[realsense]'``)
and imported only when a pipeline starts (``device.py``); ``core.py`` needs numpy only."""
