"""The ``skelfuse`` command: server, agent and demo entry points."""

__version__ = "0.1.0"
