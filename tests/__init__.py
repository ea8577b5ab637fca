"""rigcal's test suite; the folders mirror the package (app/rigcal)."""
