"""The fixed-point firmware model of lde's lateral filter (integers only; see docs/firmware_lateral.md).

The model is backend ``fixed`` (:mod:`lde.engine.backends.fixed`), checked against the float lateral
filter (:mod:`lde.estimator.lateral`, backend ``float``) at every step (:mod:`.shadow`).

Modules: ``lateral`` (the integer step, its slow task and the boundary, one source compiled by numba
and run on Python ints), ``lat_coefs`` (its coefficient polynomials), ``qformat`` (Q formats,
rounding, saturation), ``gen_lateral`` and ``gen_tables`` (the generator:
``python -m firmware_model.gen_tables``), ``tables`` (the generated constants, typed), ``riccati``
(offline DARE), ``shadow`` (the shadow check's bound), ``synthetic`` (test drives).
"""
