"""The ``avs`` command line: start the system, watch its streams, run episodes."""
