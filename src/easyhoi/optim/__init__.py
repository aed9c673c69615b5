"""Prior-guided optimization (docs/method.md section 2.2): the three stages, their loss terms,
state and loop.

Entry point: :func:`easyhoi.optim.run.optimize`. Modules: ``state`` (per-run state), ``loop``
(stage bookkeeping and the coarse-to-fine phase loop), ``placement`` (hand frames), ``losses``,
``camera`` / ``contact`` (+ ``registration``) / ``refine`` (stages 1-3), ``run``.
"""
