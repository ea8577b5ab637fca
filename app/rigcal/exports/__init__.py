"""The rig in other tools' formats (Kalibr, OpenCV, ROS, JSON, camchain-imucam, EuRoC) and the Kalibr
camchain reader."""
