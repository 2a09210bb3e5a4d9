"""Pose sources of a moving sensor: where the sensor was at each capture instant.

:class:`~skelfuse.agent.poses.base.PoseSource` is the seam; a pose file (recorded or simulated
trajectories) and OpenVR (a headset or tracker the depth camera is fixed to) implement it, and
:class:`~skelfuse.agent.poses.posed.PosedSource` attaches their poses to any skeleton source's
captures (docs/sensors.md, "Moving sensors").
"""
