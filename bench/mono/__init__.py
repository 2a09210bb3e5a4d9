"""One ordinary camera (the mono source) on the real four-camera clip."""
