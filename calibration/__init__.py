"""Where every sensor stands: pure math and persistence, no sockets or web framework."""
