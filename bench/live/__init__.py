"""The live server on loopback: load, many clients, outputs, stalls, and in-process costs."""
