"""Math several layers share and no contract defines: rotations, pinhole cameras, placing a
point set in front of a camera. The bottom layer (numpy only): :mod:`skelfuse.protocol` and
every layer above it may import it; it imports nothing of skelfuse."""
