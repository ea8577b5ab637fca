"""Data in: the dataset layout, corners files, IMU csv files, image reading, truth files, and `rigcal
ingest` (EuRoC folders, ROS bags, videos)."""
