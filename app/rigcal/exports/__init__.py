"""The rig in other tools' formats (Kalibr, OpenCV, ROS, JSON, camchain-imucam, EuRoC) and the Kalibr
camchain reader; the settings of estimators (OpenVINS, VINS-Fusion, ORB-SLAM3, basalt) and autopilots
(PX4, ArduPilot), whose frame and clock conventions are converted in exports.frames."""
