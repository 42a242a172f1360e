"""The exploration loop as a service: plan a view, drive and look there, take the frame, fuse
it, decide whether to go on (thesis Algorithm 5 in a loop, 4.5), in lockstep or on the wall
clock."""
