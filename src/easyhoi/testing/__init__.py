"""Synthetic fixtures with known answers, shared by the tests, the benchmarks and the scripts.

Import the module you need (nothing here is imported by the library itself):

* :mod:`easyhoi.testing.optim_scenes`: small hand-holding-an-object scenes with a ground-truth
  camera, hand and metric scale, for the optimizer's tests and ``benchmarks/bench_optim.py``;
* :mod:`easyhoi.testing.hoi_scene`: one finished reconstruction (and its input) of a hand on a
  box, for the exports, pictures and report;
* :mod:`easyhoi.testing.mano_synth`: files with the layout of a MANO model and made-up content
  (never MANO data), for the MANO loader, the restricted unpickler and runs with
  ``--hand-model mano``;
* :mod:`easyhoi.testing.toy_hand`: a 21-vertex hand model in the MANO joint layout.
"""
