# ruff: noqa
"""Fake of pykinect_azure.k4abt._k4abt: the frame timestamp function."""


def k4abt_frame_get_device_timestamp_usec(frame_handle):
    return frame_handle._timestamp_us
