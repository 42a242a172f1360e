"""The thesis's experiments on the robot itself (chapter 5.4), each run in the sim in lockstep
at 1 kHz, in one process, from the services' cores: no Zenoh, no service stack.

- ``gaze``: object localisation while the hip swings, stabilised or not (5.4.1, Table 5.1,
  Fig. 5.9/5.10); ``image_quality``: what its camera images are judged by (optical flow,
  blur, whether the objects are localised).
- ``grasp``: grasping a cup while the platform drives past it (5.4.2, Fig. 5.11/5.12);
  ``grasp_vision``: what it sees (colour blobs, stereo points with their covariance);
  ``servo``: the position-based visual servo that moves the hand.

Why a package of their own: they are neither a service (nothing here runs as a node or is
imported by one) nor the command line (``avs gaze-experiment`` and ``avs grasp-experiment``
parse their arguments and call into here). They may import ``services`` and ``schemas``;
nothing under ``services`` may import them.
"""
