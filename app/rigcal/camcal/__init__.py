"""Camera calibration: the per-camera start, the pose graph, the bundle adjustment with its covariance,
model selection, the output body frame, stereo depth checks and Cramer-Rao bounds."""
