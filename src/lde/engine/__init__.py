"""The one data path: the receiver, the step grid, the compiled loop, the backend registry, the Engine."""
