"""The thesis's experiments: what the command line runs and scores, not what a robot deploys.

- ``episode``: an exploration episode (chapter 4.5, Fig. 4.8, 4.11, 4.12): every service a
  local process on a loopback router, the explorer stepping the sim in lockstep, and an
  evaluator outside them that scores each view against the sim's ground truth
  (``evaluation``: InlierIndex, support-graph precision/recall/F1), writes the metrics and
  plots and the report (``report``); ``bootstrap``: the intervals ``avs compare`` claims
  orderings with.

The experiments on the robot itself (chapter 5.4) run in the sim in lockstep at 1 kHz, in one
process, from the services' cores: no Zenoh, no service stack.

- ``gaze``: object localisation while the hip swings, stabilised or not (5.4.1, Table 5.1,
  Fig. 5.9/5.10); ``image_quality``: what its camera images are judged by (optical flow,
  blur, whether the objects are localised).
- ``grasp``: grasping a cup while the platform drives past it (5.4.2, Fig. 5.11/5.12);
  ``grasp_vision``: what it sees (colour blobs, stereo points with their covariance);
  ``servo``: the position-based visual servo that moves the hand.

Why a package of their own: they are neither a service (nothing here runs as a node or is
imported by one) nor the command line (``avs explore``, ``avs compare``, ``avs score``,
``avs gaze-experiment`` and ``avs grasp-experiment`` parse their arguments and call into
here). They may import ``services`` and ``schemas``;
nothing under ``services`` may import them.
"""
