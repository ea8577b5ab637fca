"""Camera-IMU calibration: the continuous-time estimator (residual blocks, the start from rotation
rates, Levenberg-Marquardt on a spline trajectory), its inputs, and the calibrate step that runs it."""
