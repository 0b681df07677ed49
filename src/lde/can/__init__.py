"""CAN: frames, bit fields, E2E and checksums, raw <-> physical codec, profiles."""
