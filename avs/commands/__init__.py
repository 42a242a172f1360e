"""One module per ``avs`` sub-command, each with ``register(subparsers)`` and a handler."""
