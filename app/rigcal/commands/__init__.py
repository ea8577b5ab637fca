"""The library behind each CLI command that is more than a call: calibrate, project, export/import."""
