"""The maths and the model every stage shares: poses and frames, camera projection, the rig and target
schemas, board observations, continuous-time trajectories, stereo geometry, atomic file writes and
worker pools."""
