"""``lde inspect``: what a user needs to know about a log and a profile before trusting a new car.

The pieces, in the order an inspection runs them (:func:`inspection.inspect_frames`):

* :mod:`.survey`: the log's ids per channel, their rates, jitter and lengths;
* :mod:`.match`: which profile fits (its input messages, their lengths, one channel);
* :mod:`.inputs`: a profile's inputs decoded in SI, their ranges, rates, gaps and integrity;
* :mod:`.resample`: the inputs low-passed onto one time grid;
* :mod:`.relation`: a straight-line fit with autocorrelation-robust 95 % intervals;
* :mod:`.checks`: the physics checks of signs and scales, and which sign is wrong;
* :mod:`.report`: the result as text or JSON.
"""
