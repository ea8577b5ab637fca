"""Detection: boards found in images (ChArUco, AprilGrid, chessboard), corners refined, the reasons a
board is not found, and the guided re-measurement with a calibrated model."""
