"""The live service: the 3.9 ms loop, bus I/O, bus faults, timing, the hand-off to the recorder."""
