"""What a calibration produces for people: the calibrated rig YAML and its console tables, the HTML
report, the 3D rig view, and the comparison with truth."""
