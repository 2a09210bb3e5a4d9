"""Fakes of the sensor SDKs' Python APIs, put on ``sys.path`` by tests (no hardware here).

``pykinect2``: the modules keep the packaging bugs of PyKinect2 0.1.0 from PyPI (the 64-bit
``tagSTATSTG`` assert, ``_check_version``, ``time.clock``, ``numpy.object``,
``PyObject_AsWriteBuffer``), so importing them unpatched fails as the real ones do.
``pykinect_azure``: the calls skelfuse makes, with the real attribute layout (``k4a_float3_t``
union with ``.xyz``, ``confidence_level``, ``k4abt._k4abt.k4abt_frame_get_device_timestamp_usec``).
Tests script the frames through each fake's ``SCRIPT`` list.
"""
