"""Adapters: sources of AVS streams other than the sim (recorded bags, real cameras), publishing
on the same keys and schemas so perception and scene memory cannot tell the difference."""
