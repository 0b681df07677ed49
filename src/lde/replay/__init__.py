"""A log through the data path; fleets of logs on Dask; the RTS smoother."""
