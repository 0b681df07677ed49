"""The math: the 2-DOF model, the float filters (the paper's and the lateral one), online learning and its
file, input corrections, the overlay law."""
